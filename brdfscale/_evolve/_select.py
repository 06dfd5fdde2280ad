"""Resolving a path's discretisation from concrete values, once, before any tracing.

:func:`select` is the public entry (``brdfscale.select``); :func:`resolve` is what
:func:`brdfscale.evolve` calls for concrete inputs. Every choice is verified on the values it
is made for:

* radial: the cut-off K bounds the truncation error (tail criterion of :func:`cutoff`) by
  tol/2 of the peak; the node count integrates ``G(k) J₀(kr) k`` to that over every radius up
  to the support radius R (beyond it the lobe is below tol/2); the table of radii — uniform
  in ``t = asinh(K r)`` (uniform near 0 at spacing ``h/K``, geometric in the tail) — is
  refined until cubic interpolation between its nodes, checked at every midpoint against the
  quadrature itself, is within tol/2;
* grid: the side N and half-width a from the bandwidth and support radius (tol/2), then the
  zero-padded oversampling p doubled until 6 × 6-point Lagrange interpolation on the (pN)² slope grid,
  checked at every cell centre of the 2p grid, is within tol/2;
* the existence check for those values: ``|G| ≤ 1`` on the probe and no evolved value below
  −tol of the peak (table radii and midpoints, or the oversampled grid).

A resolved method is verified for the parameters it was selected with; reused with other values
(a fit's iterations) it honours its tolerance while the lobe's width and bandwidth stay
similar — re-select when they move far.
"""

import math
import numbers
import warnings

import jax.numpy as jnp
import numpy as np
import scipy.special

from .._errors import InvalidInputError, MethodNotApplicableError, NoBRDFAtScaleError, UnresolvedMethodError
from .._existence import NEGATIVE_LOBE
from .._interpolate import lagrange_stencil
from .._quadrature import gauss_legendre
from .._validation import as_float_array, is_concrete
from ..lobes import AbstractLobe
from ..stats import AbstractGeneralisedDensity, AbstractSlopeDensity
from ._algebra import has_closed_form
from ._methods import AbstractMethod, Auto, ClosedForm, Grid, Radial, RadialTable, as_method, carried, carrying
from ._regularise import check_noise, choose, needs_data, rule_name, unresolved_regularisation
from ._spectral import (GRID_POINTS, EvolvedDensity, concrete_cf_radial, concrete_cutoff, concrete_support,
                         grid_size, probe_checks, radial_nodes, radial_reach)

MIN_TOL = 1e-14
MAX_RADIAL_NODES = 8192
"""The most Gauss–Legendre nodes chosen automatically (an explicit ``nodes`` may exceed it;
SciPy builds the rule in O(n²): 1.9 s at 8192, 7.5 s at 16384, once per size)."""
MAX_GRID = 1024
"""The largest grid side chosen automatically."""
MAX_SIGN_CHECK_NODES = 2**20
"""The most Gauss–Legendre nodes the existence check uses where the method's own are fewer."""
MAX_TABLE_ENTRIES = 2**23
"""The largest radial table kernel (nodes × radii: 64 MiB in float64)."""
MAX_FINE_SIDE = 4096
"""The largest oversampled slope grid side of the grid path's table."""
TABLE_POINTS = 8
"""Lagrange points of the radial table's interpolation (error ∝ h⁸: 512 radii reach 4e-11 of
the peak for README's lobe, where cubic stencils need 4096)."""



def check_arguments(lobe, s_from, s_to, tol, regularisation, noise=None):
    """The checks :func:`brdfscale.evolve` and :func:`select` share: ``(tol, λ, rule, noise)`` —
    λ a float array (None when ``regularisation`` is None or a rule), the rule's name (None for a
    number; ``"auto"`` is the default rule) and the discrepancy rule's noise level."""
    if not isinstance(lobe, AbstractLobe):
        raise InvalidInputError(f"lobe must be a brdfscale.lobes lobe; got {type(lobe).__name__}.")
    for name, s in (("s_from", s_from), ("s_to", s_to)):
        if isinstance(s, AbstractGeneralisedDensity):
            raise InvalidInputError(
                f"{name} must be a probability density of facet slopes (mass 1); got {type(s).__name__}, "
                "a generalised function of mass 0 (a plus-distribution h_n). Use it through "
                "brdfscale.plus.NearlySpecular(a, [c_0, …], x0, ...) (a δ + Σ c_n h_n + w s_smooth, mass 1).")
        if not isinstance(s, AbstractSlopeDensity):
            raise InvalidInputError(f"{name} must be a brdfscale.stats density; got {type(s).__name__}.")
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not MIN_TOL <= tol < 1:
        raise InvalidInputError(
            f"tol must be a number in [{MIN_TOL:g}, 1) (an error relative to the lobe's peak; below "
            f"{MIN_TOL:g} float64 rounding in the evaluation exceeds it); got {tol!r}.")
    rule = rule_name(regularisation)
    noise = check_noise(rule, noise)
    if rule is not None or regularisation is None:
        return float(tol), None, rule, noise
    lam = as_float_array(regularisation, "regularisation")
    if lam.ndim != 0:
        raise InvalidInputError(f"regularisation must be one number λ ≥ 0 (or a rule's name); got shape {lam.shape}.")
    if is_concrete(lam) and float(lam) < 0:
        raise InvalidInputError(f"regularisation must be ≥ 0; got {float(lam)}.")
    return float(tol), lam, rule, noise


def regularised(method, lobe, s_from, s_to, lam, rule, noise):
    """``(λ, method)``: the λ of the division for a spectral ``method`` — a number as given; a
    rule's choice (:mod:`._regularise`), reused from a method that carries one of that rule,
    else chosen here from concrete values (UnresolvedMethodError when traced) and carried by the
    returned method; None: the method's own λ, else 0."""
    own, own_rule = carried(method)
    if rule is None:
        if lam is not None:
            return lam, method
        return (jnp.asarray(0.0) if own is None else own), method
    if own is not None and own_rule == rule:
        return own, method
    if needs_data(lobe, s_to) and not is_concrete((lobe, s_from, s_to, noise)):
        raise unresolved_regularisation(rule)
    value, how = choose(lobe, s_from, s_to, rule, noise)
    value = jnp.asarray(value)
    return value, carrying(method, value, rule, how)


def spectral_path(method: AbstractMethod, lobe, s_from, s_to) -> AbstractMethod:
    """``method`` with Auto replaced by the spectral path that applies; radial refused for
    inputs that are not radially symmetric."""
    if isinstance(method, Auto):
        method = method.select_method(lobe, s_from, s_to)
        if isinstance(method, ClosedForm):
            return method
    isotropic = lobe.shape.isotropic and s_from.isotropic and s_to.isotropic
    if isinstance(method, Radial) and not isotropic:
        raise MethodNotApplicableError(
            "method='radial' needs a radially symmetric lobe and statistics (isotropic, centred); "
            "use method='grid' for anisotropic, shifted, skewed or tabulated inputs.")
    return method


def unresolved(method: AbstractMethod) -> UnresolvedMethodError:
    what = "nodes=" if isinstance(method, Radial) else "size="
    return UnresolvedMethodError(
        f"the {method.path} path's discretisation depends on parameter values, which are traced here (inside "
        "jax.jit, grad or vmap) and so unknown; brdfscale does not fall back to a default size. Resolve it "
        "outside the transformation from concrete values, `method = brdfscale.select(lobe, s_from, s_to, "
        "tol=...)`, and pass `method=method` inside (re-select when the parameters move far), or fix the "
        f"size yourself with {type(method).__name__}({what}...).")


def select(
    lobe: AbstractLobe,
    s_from: AbstractSlopeDensity,
    s_to: AbstractSlopeDensity,
    *,
    tol: float = 1e-10,
    method: AbstractMethod | str = "auto",
    regularisation: float | str = 0.0,
    noise=None,
    check: bool = True,
) -> AbstractMethod:
    """The resolved discretisation with which :func:`brdfscale.evolve` meets ``tol``.

    Decides, from the concrete values given, the path (closed form, radial or grid — the
    first that applies, or the one forced by ``method``) and everything it needs: the
    Gauss–Legendre nodes, the cut-off K and a verified table of radii (radial); the grid side,
    half-width and a verified oversampling (grid); and checks that a BRDF exists for these
    values (module docstring). The result is a static object: pass it as
    ``evolve(..., method=result)`` inside ``jax.jit``/``grad``/``vmap``, where it is used as
    it is. ``result.explain()`` says what it chose; ``result.tol`` is the error relative to the
    lobe's peak it honours (looser than asked only when a capped grid cannot do better).

    ``regularisation``: the Tikhonov λ of the division as in :func:`brdfscale.evolve` — a
    number, or a rule (``"auto"``, ``"gcv"``, ``"discrepancy"`` with ``noise=σ``, ``"l_curve"``)
    that chooses λ from the concrete values here. A spectral result carries the λ (a rule's
    choice, or a nonzero number) and the discretisation verified for it:
    ``result.regularisation``, reported by ``result.explain()``; ``evolve(..., method=result)``
    uses it, under ``jax.jit`` too.

    Raises:
        UnresolvedMethodError: the values are traced (call it outside the transformation).
        NoBRDFAtScaleError: no non-negative lobe exists for these values.
        MethodNotApplicableError: a forced method does not apply.
        InvalidInputError: bad arguments.
    """
    tol, lam, rule, noise = check_arguments(lobe, s_from, s_to, tol, regularisation, noise)
    method = spectral_path(as_method(method), lobe, s_from, s_to)
    if isinstance(method, ClosedForm):
        if not has_closed_form(lobe.shape, s_from, s_to):
            raise MethodNotApplicableError(
                f"no closed form for a {type(lobe.shape).__name__} lobe with {type(s_from).__name__} → "
                f"{type(s_to).__name__} statistics.")
        return method
    if not is_concrete((lobe, s_from, s_to)):
        raise unresolved(method)
    lam, method = regularised(method, lobe, s_from, s_to, lam, rule, noise)
    density = EvolvedDensity(lobe.shape, s_from, s_to, lam, method, tol, check)
    if not is_concrete(density):
        raise unresolved(method)
    chosen, how = carried(method)
    if chosen is None and rule is None and float(lam) != 0:
        chosen, how = lam, "given"
    return carrying(resolve(density, method), chosen, how if rule is None else rule,
                    getattr(method, "regularisation_note", None))


def resolve(density: EvolvedDensity, method: Radial | Grid) -> Radial | Grid:
    """``method`` with every choice it leaves open made for ``density``'s concrete values."""
    if isinstance(method, Radial):
        return _resolve_radial(density, method)
    return _resolve_grid(density, method)


# -- radial ------------------------------------------------------------------------------------
def _resolve_radial(density: EvolvedDensity, method: Radial) -> Radial:
    k, mag = density._probe()
    probe_checks(density, k, mag)
    half = density.tol / 2
    K = float(method.cutoff) if method.cutoff is not None else float(concrete_cutoff(k, mag, half))
    R = float(concrete_support(density, half))
    needed = radial_nodes(K, 2 * R, half)
    nodes = method.nodes if method.nodes is not None else min(MAX_RADIAL_NODES, needed)
    sign_check = method.sign_check and nodes >= needed
    density = density.with_discretisation(Radial(nodes=nodes, cutoff=K, sign_check=sign_check))
    if density.check and not sign_check and needed <= MAX_SIGN_CHECK_NODES:
        _radial_sign_check(density, needed, K, R)  # the existence check with the nodes it needs
    table = _radial_table(density, nodes, K, R, half)
    return Radial(nodes=nodes, cutoff=K, table=table, tol=density.tol, budget=method.budget, sign_check=sign_check)


def _radial_sign_check(density, nodes, K, R, radii=128):
    """No value below −tol of the peak at ``radii`` radii out to R (uniform in asinh(K r)),
    evaluated with ``nodes`` Gauss–Legendre nodes — enough for R — even where the method's own
    are fewer (a lobe spanning many scales: δ components, heavy tails)."""
    # composite 64-point Gauss–Legendre panels (each spans ~10 oscillations of J₀ at R)
    panels = max(1, math.ceil(nodes / 64))
    x, w = gauss_legendre(64)
    edges = np.linspace(0.0, K, panels + 1)
    half = 0.5 * np.diff(edges)
    k = (edges[:-1, None] + half[:, None] * (x[None, :] + 1)).ravel()
    wk = (half[:, None] * w[None, :]).ravel()
    G = np.asarray(concrete_cf_radial(density, jnp.asarray(k)), dtype=float)
    r = np.sinh(np.linspace(0, math.asinh(R * K), radii)) / K
    values = _j0_rows(wk * k * G / (2 * np.pi), k, r)
    if np.min(values) < -density.tol * np.max(values):
        raise NoBRDFAtScaleError(NEGATIVE_LOBE)


def _j0_rows(c, k, r, chunk=1 << 22):
    """``Σ_i c_i J₀(k_i r_j)`` for every r_j, in chunks of radii (NumPy, SciPy's J₀)."""
    per = max(1, chunk // len(k))
    return np.concatenate([c @ scipy.special.j0(np.outer(k, r[i:i + per])) for i in range(0, len(r), per)])


def _radial_table(density, nodes, K, R, half) -> RadialTable | None:
    """A table of radii out to R whose cubic interpolation is verified within ``half`` of the
    peak at every midpoint, and the existence check on its values (None when the nodes do not
    reach R — queries are then evaluated directly — or no table fits MAX_TABLE_ENTRIES)."""
    x, w = gauss_legendre(nodes)
    k = 0.5 * (x + 1) * K
    G = np.asarray(concrete_cf_radial(density, jnp.asarray(k)), dtype=float)
    c = 0.5 * K * w * k * G / (2 * np.pi)
    scale = 1 / K
    t_end = math.asinh(R / scale)
    count = 64
    reach = radial_reach(K, nodes, half)
    while True:
        h = t_end / count
        # every node and midpoint: 3 mirror nodes below t = 0 (g is even), 5 beyond t_end
        t_fine = (np.arange(2 * (count + 9) - 1) / 2 - 3) * h
        fine = _j0_rows(c, k, scale * np.sinh(t_fine))
        peak = float(np.max(fine))
        if density._sign_check and np.min(fine) < -density.tol * peak:
            raise NoBRDFAtScaleError(NEGATIVE_LOBE)
        if reach < 2 * R:  # nodes too few for radii out to R: no table, queries evaluated directly
            return None
        coarse, mid = fine[::2], fine[1::2]
        positions = np.arange(len(mid)) + 0.5
        base, weights = lagrange_stencil(positions, len(coarse), TABLE_POINTS, xp=np)
        guess = np.sum(coarse[base[:, None] + np.arange(TABLE_POINTS)] * weights, axis=1)
        inside = t_fine[1::2] <= t_end + h  # radii the table serves
        error = float(np.max(np.abs(guess - mid)[inside]) / peak)
        if error <= half:
            r = scale * np.sinh(t_fine[::2])
            kernel = scipy.special.j0(np.outer(k, r))
            return RadialTable(jnp.asarray(kernel), scale, h, float(R), error, TABLE_POINTS)
        count *= 2
        if nodes * (count + 9) > MAX_TABLE_ENTRIES:
            return None


# -- grid --------------------------------------------------------------------------------------
def _resolve_grid(density: EvolvedDensity, method: Grid) -> Grid:
    k, mag = density._probe()
    probe_checks(density, k, mag)
    sign_check = method.sign_check
    if method.size is None:
        size, truncation = grid_size(density, MAX_GRID, k, mag)
        honoured = max(density.tol, 2 * truncation)
    else:
        size, honoured = method.size, density.tol
        try:
            needed, _ = grid_size(density, max(MAX_GRID, size), k, mag)
        except InvalidInputError as err:  # no automatic size resolves it: the caller's own size stands
            warnings.warn(f"{err} Evaluating with size={size} as given: expect errors well above tol.", stacklevel=4)
            sign_check = False
        else:
            if size < needed:
                warnings.warn(
                    f"size={size} is below the {needed} nodes per side that tol={density.tol:g} needs on this "
                    f"grid; expect errors well above tol (leave size=None to choose it).", stacklevel=4)
                sign_check = False
    support = float(concrete_support(density, honoured / 2))
    if method.extent is None:
        extent = support
    else:
        extent = float(method.extent)
        if extent < support:
            warnings.warn(
                f"extent={extent:g} is inside the radius {support:.3g} beyond which the lobe is below tol/2 of its "
                "peak: offsets outside the grid evaluate to 0 and the lobe's tail aliases into it; expect errors "
                "above tol (leave extent=None to choose it).", stacklevel=4)
            sign_check = False
    d = density.with_discretisation(Grid(size=size, extent=extent, budget=method.budget, sign_check=sign_check),
                                    honoured)
    oversample, error = method.oversample, None
    if oversample is None:
        oversample, error = _oversampling(d, size, honoured / 2)
    values = d.on_grid(1)[1]  # the existence check on the grid (raises NoBRDFAtScaleError)
    del values
    return Grid(size=size, extent=extent, oversample=oversample, tol=honoured, error=error, budget=method.budget,
                sign_check=sign_check)


def _oversampling(density, size, half):
    """The smallest p (2, 4, …) whose (pN)² grid bicubic interpolation reads within ``half``
    of the peak, checked at every cell centre against the 2p grid; (None, None) when no p
    with 2pN ≤ MAX_FINE_SIDE does."""
    p = 2
    while 2 * p * size <= MAX_FINE_SIDE:
        coarse = np.asarray(density.on_grid(p)[1])
        fine = np.asarray(density.on_grid(2 * p)[1])
        n = coarse.shape[0]
        centres = np.arange(n - 1) + 0.5
        by, wy = lagrange_stencil(centres, n, GRID_POINTS, xp=np)
        stencil = by[:, None] + np.arange(GRID_POINTS)
        # separable: along x, then along y
        along_x = np.einsum("ysk,sk->ys", coarse[:, stencil], wy)
        guess = np.einsum("sky,sk->sy", along_x[stencil, :], wy)
        error = float(np.max(np.abs(guess - fine[1:-1:2, 1:-1:2][: n - 1, : n - 1])) / np.max(fine))
        if error <= half:
            return p, error
        p *= 2
    return None, None
