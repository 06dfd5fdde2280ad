"""Smith's masking function Λ of any facet-slope density (issue 32 item 4; docs/masking.md).

For a surface whose facet slopes ``m`` (docs/conventions.md §1) have the density ``s`` and a
direction ``w`` (``w_z > 0``) of polar angle θ and azimuth φ, Smith's Λ is

    Λ(w) = (1/μ) ∫_μ^∞ (q − μ) P₂(q) dq,     μ = cot θ,

``P₂`` the 1-D marginal of ``s`` along the azimuth, ``q = e·m`` with ``e = (cos φ, sin φ)``
(Smith 1967; Heitz 2014, "Understanding the masking-shadowing function", in slope form).
With ``v = (w_x, w_y)/w_z = e/μ`` (the direction's own slope vector, ``|v| = tan θ``) the
same number is one expectation of a hinge,

    Λ(w) = E_s[(v·(m − c) − 1)₊],

which is what this module computes: no division by μ, ``Λ = 0`` exactly at normal incidence
(v = 0) and ``Λ ≈ |v| E[(e·(m − c))₊]`` growing linearly towards grazing.

**Off-centre densities.** Smith's Λ is defined for slopes measured from the surface's mean
plane, whose mean slope is zero. A density of mean ``c ≠ 0`` (a lobe shape peaked off the
specular slope, a tilted table) is centred first: ``c`` is subtracted from every slope, and the
direction is not rotated (the nearly-flat reading of "slopes relative to the mean plane";
:class:`brdfscale.lobes.SmithMasking` rotates directions into the frame of a macroscopic tilt
``m∞``). Along an azimuth this is the marginal ``P₂`` centred by its own mean ``e·c``. The
mean is the density's ``mean`` for the closed forms, the weighted mean of the components for
a :class:`Mixture`, and otherwise read from the transform,
``E[e·m] = −Im S'(0 e)`` (a Richardson-extrapolated difference quotient of ``Im S(h e)/h``).

**Closed forms** (``X = v·(m − c)``):

* :class:`Gaussian` (Beckmann ``α``: ``Σ = α²/2``): X is normal of variance ``vᵀΣv`` (the
  projected variance), ``E[(X − 1)₊] = s φ(1/s) − Φ(−1/s)`` with ``s² = vᵀΣv``; for isotropic
  Beckmann, ``a = μ/α``: ``Λ = (erf a − 1)/2 + e^{−a²}/(2a√π)``.
* :class:`GGX` (``A = diag(α_x, α_y)``): X is a Student-t with two degrees of freedom and scale
  ``α_v/√2``, ``α_v² = |A v|²`` (the projected α), ``E[(X − 1)₊] = (√(1 + α_v²) − 1)/2``; for
  isotropic GGX ``Λ = (−1 + √(1 + 1/a²))/2``.
* :class:`Delta` (a flat plane): ``Λ = 0`` after centring.
* :class:`Mixture`: Λ is linear in the density for a common centre, ``Λ = Σ w_k E_k[(X − 1)₊]``
  with the mixture's mean removed from every component (so a blazed mixture of point masses
  is exact).
* :class:`PixelGaussians` (a lobe image's pixels, equal Gaussians on the nodes): the same mixture
  rule over its nodes, vectorised (one normal closed form per pixel and direction).
* :class:`Tabulated` (a table's tent sum, ``s = Σ_p v_p Λ_x Λ_y``): the same mixture rule over its
  nodes, exact. A tent of node ``p`` projects onto ``v`` as ``a_p + A S + B T`` with
  ``a_p = v·(m_p − c)``, ``A = |v_x| h_x``, ``B = |v_y| h_y`` and S, T independent triangular on
  [−1, 1], so ``Λ = Σ_p h_x h_y v_p E[(a_p − 1 + A S + B T)₊]``. The inner expectation over S is a
  cubic spline in closed form, ``E[(b + A S)₊] = A g(b/A)`` with ``g(u) = (1 + u)³/6`` on [−1, 0],
  ``u + (1 − u)³/6`` on [0, 1] (``b₊`` beyond); the one over T is a piecewise polynomial of degree
  ≤ 4 between the break points ``t ∈ {−1, 0, 1}`` and where ``b = a + B t`` crosses ``−A, 0, A``,
  so three Gauss–Legendre points per piece integrate it exactly. No cancellation: every piece is
  evaluated where it holds, ``A → 0`` or ``B → 0`` included. Its mean is ``center + h_x h_y Σ_p v_p
  m_p`` (tents are symmetric). The cost is O(nodes) per direction, where the transform's
  quadrature of the generic path costs O(nodes × :data:`NODES`) (experiments/bench_masking.py
  measures both).

**The generic path** (every other density: :class:`Tabulated`, :class:`StudentT`, evolved
shapes of :func:`brdfscale.evolve`, observed nearly-specular statistics, …) needs only the
transform ``S(W)`` on the line ``W = k e``, which is the transform of ``P₂`` (projection-slice
theorem). With ``T(x) = E[(e·(m − c) − x)₊]`` (so ``Λ = |v| T(1/|v|)``) and a reference normal
density ``Y ~ N(0, σ_ref²)``,

    T(x) = T_ref(x) + (1/π) ∫_0^∞ Re[(S_ref(k) − S(k e) e^{ik e·c}) e^{ikx}] / k² dk,

from ``E|Z| = (2/π) ∫_0^∞ (1 − Re E e^{ikZ})/k² dk``. The reference removes the ``1/k²`` that
the kink of the hinge puts into the integrand: the remaining integrand is smooth (for
densities with a variance) and decays as ``S`` does. It is summed by the midpoint rule on
:data:`NODES` nodes ``k_j = (j + ½)Δk``. By Poisson summation the rule is exact for the
periodised difference ``T − T_ref`` of period ``2π/Δk``; ``Δk ≤ 2π/(4R)`` with ``R`` the
support radius (at :data:`TOL`) plus ``|c|``, so the periodic images stay beyond the support,
and the nodes reach ``K = max(bandwidth(TOL), 60/R)``, where ``|S| ≤ TOL`` (Δk smaller when
that bandwidth is narrow). For ``x > R`` (directions near normal incidence, where the hinge
lies beyond the support) the integral is taken at ``x = R``: an error of at most the tail mass
beyond R. The nodes are fixed by ``stop_gradient`` (the quadrature is a differentiable
function of the density's parameters). Heavy tails cost accuracy: a Student-t of small ν
reaches far (R grows), and without a first moment (ν ≤ 1) Λ is infinite and refused.

Point masses have a transform that does not decay: a bare :class:`Delta` and mixtures with
one are exact above; any other density whose concrete bandwidth is infinite is refused (its
integral would not converge) with :class:`brdfscale.InvalidInputError`.

Verified in tests/test_masking.py: the closed forms against SciPy/mpmath, the generic path
against SciPy quadrature of the definition for random tabulated densities (the 2-D density
marginalised numerically) and against the closed forms (Gaussian and GGX evaluated through
the generic path), jit/grad/vmap against eager, float32 against float64.
"""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc, erfcx
from jaxtyping import Array, ArrayLike, Float

from .._blocks import in_blocks
from .._errors import InvalidInputError
from .._slopes import safe_norm
from .._validation import is_concrete
from ._base import AbstractSlopeDensity
from ._families import Delta, Gaussian, GGX
from ._mixture import Mixture
from ._pixels import PixelGaussians
from ._require import require_density
from ._student import StudentT
from ._tabulated import Tabulated


__all__ = ["mean_slope", "smith_lambda"]

NODES = 1024
"""Midpoint nodes of the generic path's Fourier integral (module docstring)."""

TOL = 1e-9
"""Relative level at which the generic path takes a density's support radius and bandwidth."""

_BYTES_PER_NODE = 16 * 64
"""Temporaries per direction and node of the generic path (a complex transform value and its
evaluation's intermediates; blocks of directions keep them within the budget of brdfscale._blocks)."""


def smith_lambda(density: AbstractSlopeDensity, w: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch"]:
    """Smith's ``Λ(w)`` of a surface whose facet slopes have the density ``density``.

    ``Λ(w) = (1/μ) ∫_μ^∞ (q − μ) P₂(q) dq`` with ``μ = cot θ_w`` and ``P₂`` the marginal of the
    (centred) density along w's azimuth; computed as ``E[(v·(m − c) − 1)₊]``, ``v = w_xy/w_z``,
    ``c`` the density's mean (module docstring: closed forms for Gaussian/Beckmann, GGX, Delta and
    mixtures, one Fourier quadrature for every other density).

    Args:
        density: a :class:`brdfscale.stats.AbstractSlopeDensity` (the generic path needs it
            unbatched; map batches with ``jax.vmap``).
        w: unit directions (..., 3) with ``w_z > 0`` (the frame of docs/conventions.md §1).

    Returns:
        Λ ≥ 0 with w's batch shape: 0 at normal incidence, growing as ``tan θ`` towards grazing.

    Raises:
        InvalidInputError: ``density`` is not a slope density; ``w`` is not unit directions in
            the upper hemisphere; the density has no first moment (Student-t with ν ≤ 1: Λ = ∞)
            or a transform that does not decay outside the closed forms (a point mass inside a
            non-mixture density).
    """
    from ..geometry import validate_directions

    density = require_density(density, "density")
    w = validate_directions(w, "w")
    _check(density)
    return _smith_lambda(density, w)


@eqx.filter_jit
def _smith_lambda(density: AbstractSlopeDensity, w: Array) -> Array:
    """Λ of validated directions (compiled once per density structure and batch shape)."""
    v = w[..., :2] / w[..., 2:3]
    return _hinge(density, v, _mean(density))


def _check(density: AbstractSlopeDensity) -> None:
    """The refusals of :func:`smith_lambda`, for concrete parameters (module docstring): a Student-t
    without a first moment; a density outside the closed forms whose transform does not decay."""
    if isinstance(density, Mixture):
        for component in density.components:
            _check(component)
    elif isinstance(density, StudentT):
        if is_concrete(density.nu) and not float(density.nu) > 1:
            raise InvalidInputError(
                f"a Student-t slope density with ν = {float(density.nu):g} ≤ 1 has no first moment: its slopes' "
                "tails make Smith's Λ infinite (every direction fully masked). Λ is finite for ν > 1."
            )
    elif not isinstance(density, (Delta, Gaussian, GGX, PixelGaussians)):
        band = density.bandwidth(TOL)
        if is_concrete(band) and not np.isfinite(float(band)):
            raise InvalidInputError(
                f"Smith's Λ of a {type(density).__name__} whose transform does not decay (it has a point mass) "
                "cannot be computed by the transform's quadrature; a point mass is exact as stats.Delta or as a "
                "component of a stats.Mixture, and a nearly-specular statistic has a Λ once observed through an "
                "instrument's kernel (plus.observe)."
            )


def _minus(mean, c):
    """``mean − c`` where None stands for the origin (no constant of another precision enters)."""
    if c is None:
        return mean
    return -c if mean is None else mean - c


# -- the mean ---------------------------------------------------------------------------------


def mean_slope(density: AbstractSlopeDensity) -> Float[Array, "2"]:
    """The density's mean slope ``E[m]`` (2,): the centre Smith's Λ measures slopes from.

    Closed forms for :class:`Delta`, :class:`Gaussian` and :class:`GGX` (their ``mean``), the
    centroid of :class:`PixelGaussians` and :class:`Tabulated` nodes, the weighted mean of a
    :class:`Mixture`'s components, and otherwise ``−Im ∇S(0)`` from the transform (a
    Richardson-extrapolated difference quotient; module docstring). Verified in
    tests/test_masking.py against the sample mean of the density on a grid.
    """
    density = require_density(density, "density")
    mean = _mean(density)
    return jnp.zeros(2) if mean is None else jnp.asarray(mean)


def _mean(density: AbstractSlopeDensity) -> Array | None:
    """The density's mean slope (2,) or (..., 2), None for the origin (module docstring)."""
    if isinstance(density, (Delta, Gaussian, GGX)):
        return density.mean
    if isinstance(density, PixelGaussians):
        return density.centroid()
    if isinstance(density, Tabulated):
        x, y = density.nodes()
        h = density.spacing
        mass = h[0] * h[1] * density.values
        mean = jnp.stack([jnp.sum(mass.sum(axis=0) * x), jnp.sum(mass.sum(axis=1) * y)])
        return mean if density.center is None else mean + density.center
    if isinstance(density, Mixture):
        means = [_mean(c) for c in density.components]
        terms = [w * m for w, m in zip(density.weights, means) if m is not None]
        return functools.reduce(jnp.add, terms) if terms else None
    return _transform_mean(density)


def _transform_mean(density: AbstractSlopeDensity) -> Array:
    """``E[m] = −Im ∇S(0)`` by difference quotients ``f(h) = −Im S(h e_a)/h = E[sin(h m_a)]/h``
    combined as ``(4 f(h) − f(2h))/3`` (error O(h⁴) for densities with five moments), h = 10⁻²/R."""
    R = jax.lax.stop_gradient(jnp.asarray(density.support_radius(TOL)))
    h = 1e-2 / jnp.maximum(R, jnp.finfo(jnp.result_type(R, float)).tiny)
    W = jnp.stack([jnp.eye(2, dtype=h.dtype) * h, jnp.eye(2, dtype=h.dtype) * 2 * h])  # (2 steps, 2 axes, 2)
    f = -jnp.imag(density.cf(W)) / jnp.stack([h, 2 * h])[:, None]
    return (4 * f[0] - f[1]) / 3


# -- the expectation of the hinge ---------------------------------------------------------------


def _along(v: Array, offset) -> Array:
    """``v·offset`` (0 for None)."""
    return jnp.zeros(v.shape[:-1], v.dtype) if offset is None else jnp.sum(v * offset, axis=-1)


def _hinge(density: AbstractSlopeDensity, v: Array, c: Array | None) -> Array:
    """``E[(v·(m − c) − 1)₊]`` for the density's slopes m and a given centre c (None: the origin)."""
    if isinstance(density, Delta):
        return jnp.maximum(_along(v, _minus(density.mean, c)) - 1.0, 0.0)
    if isinstance(density, Gaussian):
        s2 = jnp.einsum("...i,...ij,...j->...", v, density.cov, v)  # projected variance vᵀΣv
        return _normal_hinge(_along(v, _minus(density.mean, c)), s2)
    if isinstance(density, GGX):
        alpha_v2 = jnp.sum((v * density.alpha) ** 2, axis=-1)  # projected α²: |A v|²
        return _t2_hinge(_along(v, _minus(density.mean, c)), alpha_v2)
    if isinstance(density, Mixture):
        return functools.reduce(
            jnp.add, [w * _hinge(comp, v, c) for w, comp in zip(density.weights, density.components)]
        )
    if isinstance(density, PixelGaussians):
        return _pixel_hinge(density, v, c)
    if isinstance(density, Tabulated):
        return _tabulated_hinge(density, v, c)
    return _generic_hinge(density, v, c)


def _normal_hinge(d, s2):
    """``E[(X − 1)₊]`` for X normal of mean d and variance s2 (s2 = 0 allowed: ``(d − 1)₊``).

    ``E[(X − t)₊] = (d − t) Φ(z) + s φ(z)``, ``z = (d − t)/s``; for z < 0 written with erfcx,
    ``s e^{−z²/2} (1/√(2π) + (z/2) erfcx(−z/√2))``, so that it underflows gracefully."""
    positive = s2 > 0
    s = jnp.sqrt(jnp.where(positive, s2, 1.0))
    gap = d - 1.0
    z = gap / s
    zn = jnp.minimum(z, 0.0)
    below = s * jnp.exp(-0.5 * zn**2) * (1 / math.sqrt(2 * math.pi) + 0.5 * zn * erfcx(-zn / math.sqrt(2)))
    zp = jnp.maximum(z, 0.0)
    above = gap * (1 - 0.5 * erfc(zp / math.sqrt(2))) + s * jnp.exp(-0.5 * zp**2) / math.sqrt(2 * math.pi)
    return jnp.where(positive, jnp.where(z < 0, below, above), jnp.maximum(gap, 0.0))


def _t2_hinge(d, alpha_v2):
    """``E[(X − 1)₊]`` for X Student-t (ν = 2) of location d and scale ``α_v/√2``:
    ``(√(α_v² + (1 − d)²) − (1 − d))/2``, written as ``α_v²/(2(√(α_v² + g²) + g))`` for g = 1 − d > 0."""
    g = 1.0 - d
    r2 = alpha_v2 + g**2
    r = jnp.sqrt(jnp.where(r2 > 0, r2, 1.0))
    stable = alpha_v2 / (2 * jnp.where(g > 0, r + g, 1.0))
    return jnp.where(g > 0, stable, jnp.where(r2 > 0, (r - g) / 2, 0.0))


def _pixel_hinge(density: PixelGaussians, v: Array, c: Array | None) -> Array:
    """The mixture rule over the pixel Gaussians, ``Σ_p w_p E[(X_p − 1)₊]`` with X_p normal of mean
    ``v·(node_p + center − c)`` and variance ``s²|v|²``, in blocks of directions."""
    nodes = density.nodes().reshape(-1, 2)
    offset = _minus(density.center, c)
    if offset is not None:
        nodes = nodes + offset
    weights = density.values.reshape(-1)
    shape = v.shape[:-1]

    def rows(block):
        d = block @ nodes.T  # (rows, pixels)
        s2 = density.variance * jnp.sum(block**2, axis=-1, keepdims=True)
        return _normal_hinge(d, s2) @ weights

    flat = jnp.reshape(v, (-1, 2))
    return jnp.reshape(in_blocks(rows, flat, 8 * 8 * nodes.shape[0]), shape)


_GAUSS3 = (np.array([-math.sqrt(0.6), 0.0, math.sqrt(0.6)]), np.array([5 / 9, 8 / 9, 5 / 9]))
"""Three-point Gauss–Legendre nodes and weights on [−1, 1]: exact for polynomials of degree ≤ 5."""


def _row_hinges(values: Array, h) -> tuple[Array, Array, Array]:
    """For each row ``f`` of ``values`` (a tent sum along the row, spacing ``h``, bordered by a zero node at each
    end), ``K(x) = ∫ f(m)(m − x)₊ dm`` and its tail mass ``F(x) = ∫_x^∞ f`` (``K' = −F``, ``K'' = f``) at the knots
    ``X_k = X_0 + k h`` (k = 0 … n + 1; ``X_0`` one spacing below the first node), by the exact recursion from the
    right ``F_k = F_{k+1} + h(f_k + f_{k+1})/2``, ``K_k = K_{k+1} + h F_{k+1} + h²(f_k/6 + f_{k+1}/3)``.
    Returns ``(f, K, F)`` of shape (rows, n + 2)."""
    f = jnp.pad(values, ((0, 0), (1, 1)))
    mass = h * (f[:, :-1] + f[:, 1:]) / 2  # per cell
    moment = h**2 * (f[:, :-1] / 6 + f[:, 1:] / 3)  # ∫_cell f(m)(m − X_k) dm

    def from_right(a):  # Σ_{l ≥ k} a_l, then 0 at the last knot: sums of terms ≥ 0, no cancellation
        return jnp.pad(jnp.cumsum(a[:, ::-1], axis=1)[:, ::-1], ((0, 0), (0, 1)))

    F = from_right(mass)
    K = from_right(moment + h * F[:, 1:])
    return f, K, F


def _hinge_at(x: Array, start, h, tables: tuple[Array, Array, Array], flip) -> Array:
    """``K(x)`` of every row (:func:`_row_hinges`, stacked: index 0 the rows, 1 the rows reflected, picked by
    ``flip``) at ``x`` (rows, …): the cubic of x's cell ``K_k − F_k s + f_k s²/2 + (f_{k+1} − f_k) s³/(6h)``,
    ``s = x − X_k``; left of the knots the line ``K_0 + F_0 (X_0 − x)``, right of them 0."""
    f, K, F = tables  # (2, rows, knots)
    _, count, knots = f.shape
    last = knots - 1
    g = (x - start) / h
    k = jnp.clip(jnp.floor(g), 0, last - 1).astype(jnp.int32)
    s = x - (start + k * h)
    row = (flip.astype(jnp.int32) * count + jnp.arange(count).reshape((-1,) + (1,) * (x.ndim - 1))) * knots
    fk, fk1, Kk, Fk = (jnp.take(a.reshape(-1), row + k + d) for a, d in ((f, 0), (f, 1), (K, 0), (F, 0)))
    inside = Kk - Fk * s + fk * s**2 / 2 + (fk1 - fk) * s**3 / (6 * h)
    K0, F0 = (jnp.take(a.reshape(-1), row) for a in (K, F))
    return jnp.where(g <= 0, K0 - F0 * (x - start), jnp.where(g >= last, 0.0, inside))


def _sweep(tables, start, h, across, h_across, along, side, b0) -> Array:
    """``h_a |v_l| Σ_j E_T[K_j((b0 − v_a a_j − v_a h_a T)/|v_l|)]`` for one direction (scalars ``along`` = v_l the
    component along the rows, ``side`` = v_a across them; ``across`` the rows' positions a_j; K of the rows
    reflected where v_l < 0), T triangular on [−1, 1] (module docstring); exact: K is cubic between knots, the
    tent linear, three Gauss points per piece."""
    gx, gw = _GAUSS3
    gx, gw = jnp.asarray(gx, h.dtype), jnp.asarray(gw, h.dtype)
    scale = jnp.abs(along)
    safe = jnp.where(scale > 0, scale, 1.0)
    centre = (b0 - side * across) / safe  # (rows,): the hinge's position along the row at T = 0
    slope = side * h_across / safe  # the position moves by −slope·T, |slope| ≤ h
    # the pieces in T: −1, 0, 1 and where the position crosses a knot near it (virtual knots are harmless)
    k0 = jnp.floor((centre - start) / h)
    knots = start + (k0[:, None] + jnp.arange(-1.0, 3.0, dtype=h.dtype)) * h  # (rows, 4)
    cross = (centre[:, None] - knots) / jnp.where(slope != 0, slope, 1.0)
    cross = jnp.where(slope != 0, jnp.clip(cross, -1.0, 1.0), 0.0)
    fixed = jnp.broadcast_to(jnp.array([-1.0, 0.0, 1.0], h.dtype), (centre.shape[0], 3))
    edges = jnp.sort(jnp.concatenate([fixed, cross], axis=1), axis=1)  # (rows, 7)
    mid, half = (edges[:, 1:] + edges[:, :-1]) / 2, (edges[:, 1:] - edges[:, :-1]) / 2
    t = mid[..., None] + half[..., None] * gx  # (rows, 6 pieces, 3 points)
    value = _hinge_at(centre[:, None, None] - slope * t, start, h, tables, along < 0)
    total = jnp.sum(value * (1 - jnp.abs(t)) * gw * half[..., None])
    return jnp.where(scale > 0, h_across * scale * total, 0.0)


def _tabulated_hinge(density: Tabulated, v: Array, c: Array | None) -> Array:
    """``E[(v·(m − c) − 1)₊]`` of a table's tent sum, exactly, at O(rows + columns) per direction (module
    docstring): summed along the table's rows when ``|v_x| h_x ≥ |v_y| h_y``, else along its columns."""
    x, y = density.nodes()
    h = density.spacing
    dtype = jnp.result_type(v.dtype, density.values.dtype)
    values = density.values.astype(dtype)
    offset = _minus(density.center, c)
    b0 = 1.0 - _along(v, offset)  # the hinge in the table's own coordinates: v·d − b0, d = m − center

    def both(table, step):  # f(m) and f(−m) along each row: the nodes are symmetric about 0
        return tuple(jnp.stack(pair) for pair in zip(_row_hinges(table, step), _row_hinges(table[:, ::-1], step)))

    rows, cols = both(values, h[0]), both(values.T, h[1])
    start_x, start_y = -density.extent[0] - h[0], -density.extent[1] - h[1]

    def one(vv, b):
        along_x = _sweep(rows, start_x, h[0], y, h[1], vv[0], vv[1], b)
        along_y = _sweep(cols, start_y, h[1], x, h[0], vv[1], vv[0], b)
        return jnp.where(jnp.abs(vv[0]) * h[0] >= jnp.abs(vv[1]) * h[1], along_x, along_y)

    flat_v = jnp.reshape(v, (-1, 2)).astype(dtype)
    flat_b = jnp.reshape(jnp.broadcast_to(b0, v.shape[:-1]), (-1,)).astype(dtype)
    per_direction = 8 * 2 * 18 * 12 * (values.shape[0] + values.shape[1])  # two sweeps' temporaries
    out = in_blocks(lambda block: jax.vmap(one)(*block), (flat_v, flat_b), per_direction)
    return jnp.maximum(jnp.reshape(out, v.shape[:-1]), 0.0)


def _generic_hinge(density: AbstractSlopeDensity, v: Array, c: Array | None, nodes: int = NODES) -> Array:
    """The Fourier quadrature of the module docstring, for an unbatched density."""
    K_band = jax.lax.stop_gradient(jnp.asarray(density.bandwidth(TOL)))
    c = jnp.zeros(2, v.dtype) if c is None else jnp.asarray(c)
    dtype = jnp.result_type(v.dtype, c.dtype)
    R = jax.lax.stop_gradient(jnp.asarray(density.support_radius(TOL), dtype) + jnp.linalg.norm(c))
    R = jnp.maximum(R, jnp.finfo(dtype).tiny ** 0.25)
    K = jnp.maximum(K_band.astype(dtype), 60.0 / R)
    dk = jnp.minimum(2 * jnp.pi / (4 * R), K / nodes)
    k = (jnp.arange(nodes, dtype=dtype) + 0.5) * dk  # midpoint nodes
    sigma_ref = R / 8
    reference = jnp.exp(-0.5 * (k * sigma_ref) ** 2)

    r = safe_norm(v)
    e = v / jnp.where(r > 0, r, 1.0)[..., None]
    x = jnp.minimum(1.0 / jnp.where(r > 0, r, 1.0), R)  # the hinge's position along e, at most R

    def integral(rows):
        e_rows, x_rows = rows
        W = k[:, None] * e_rows[:, None, :]  # (rows, nodes, 2)
        centred = density.cf(W) * jnp.exp(1j * k * jnp.sum(e_rows * c, axis=-1)[:, None])
        f = jnp.real((reference - centred) * jnp.exp(1j * k * x_rows[:, None])) / k**2
        return jnp.sum(f, axis=-1) * dk / jnp.pi

    shape = r.shape
    flat = (jnp.reshape(e, (-1, 2)).astype(dtype), jnp.reshape(x, (-1,)).astype(dtype))
    difference = jnp.reshape(in_blocks(integral, flat, _BYTES_PER_NODE * nodes), shape)
    # Λ ≥ 0: the sum's rounding (~1e-16) must not make it negative where Λ vanishes
    return jnp.maximum(_normal_hinge(jnp.zeros_like(r), (r * sigma_ref) ** 2) + r * difference, 0.0)
