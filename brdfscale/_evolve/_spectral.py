"""The evolved lobe as a spectral quotient; the two paths that invert its transform own the inversion.

Seed Eq. 4.4 in terms of the facet-slope densities (docs/conventions.md §2): the lobe at the target
scale has the transform

    G_to(W) = G_from(W) · S_from(W) / S_to(W).

:class:`EvolvedDensity` holds the three factors and evaluates ``G_to`` exactly; the density
``g_to(u) = (2π)⁻² ∫ G_to(W) e^{+iW·u} d²W`` is then obtained by

* the radial (Hankel) path (:class:`~brdfscale.Radial`, ``_radial.py``), when all three
  factors are radially symmetric: ``g(r) = (2π)⁻¹ ∫_0^K G(k) J₀(k r) k dk``, Gauss–Legendre
  in k on [0, K] — at the query radii, or (many queries) on a table of radii verified by
  :func:`brdfscale.select` and read off by 8-point Lagrange interpolation; or
* the grid path (:class:`~brdfscale.Grid`, ``_grid.py``): ``G`` sampled on a regular
  frequency grid and summed directly at query offsets (a non-uniform inverse DFT), or (many
  queries) inverted by one zero-padded real FFT onto a finer slope grid read off by 6 × 6-point
  Lagrange interpolation; offsets outside the grid's half-width evaluate to 0 (the lobe is
  below the error target there), never to a periodic image.

:class:`AbstractSpectralMethod` is their abstract base: what both share (the Tikhonov λ of the
division, resolution for :func:`brdfscale.select`, evaluation for :func:`brdfscale.evolve`) is
written here once; each path's own inversion is in its module.

Queries are evaluated in blocks whose temporaries stay within the method's memory budget
(:mod:`brdfscale._blocks`), so any number of offsets can be asked for.

Division uses Tikhonov regularisation, ``1/S → S*/(|S|² + λ²)``: ``λ = 0`` (the default) is
the exact Eq. 4.4; a positive λ suppresses the frequencies where ``|S_to| ≲ λ``. For
tabulated or noisy input let the data choose it, ``evolve(..., regularisation="auto")``
(generalised cross-validation, :mod:`brdfscale._evolve._regularise`); see :func:`brdfscale.evolve`.
"""

import abc
import dataclasses
import math
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InvalidInputError, NoBRDFAtScaleError, UnresolvedMethodError
from .._existence import (
    attach,
    NEGATIVE_LOBE,
    TRANSFORM_ABOVE_ONE,
    transform_exceeds_one,
    translated,
)
from .._slopes import check_slopes, shifted_cf
from .._validation import integer, is_concrete
from ..lobes import AbstractLobe, Lobe
from ..stats import AbstractSlopeDensity, Delta, Gaussian
from ._method import AbstractMethod
from ._regularise import choose, needs_data, unresolved_regularisation


_PROBE_DIRECTIONS = 8
_PROBE_POINTS = 206  # 9 decades, ~23 per decade
_PROBE_POINTS_BEYOND = 24  # 8 per decade: beyond the grid, |G| is only watched for growth
CORE_TOL = 1e-3
"""The probe's frequency window is scaled to the lobe's extent at this level (of its peak)."""


class AbstractSpectralMethod(AbstractMethod):
    """A path that inverts the evolved transform numerically (module docstring)."""

    size_argument: ClassVar[str]
    """The constructor argument that fixes the discretisation's size (``"nodes"``, ``"size"``)."""
    # fields every spectral path declares (in its own order: the constructors' positional arguments)
    tol: eqx.AbstractVar[float | None]
    budget: eqx.AbstractVar[int]
    sign_check: eqx.AbstractVar[bool]
    regularisation: eqx.AbstractVar[Float[Array, ""] | None]
    regularisation_rule: eqx.AbstractVar[str | None]
    regularisation_note: eqx.AbstractVar[str | None]

    @property
    @abc.abstractmethod
    def resolution(self) -> int | None:
        """Gauss–Legendre nodes (radial) or grid side (grid); None: not yet chosen."""

    @property
    def resolved(self) -> bool:
        return self.resolution is not None

    @property
    def half_width(self) -> Float[Array, ""] | None:
        """The slope half-width the discretisation covers as given (None: from the support radius)."""
        return None

    def show_sizes(self) -> list[tuple[str, Any]]:
        """The items an evolved lobe shows for its discretisation."""
        return [(self.size_argument, self.resolution)]

    def check_queries(self, density: "EvolvedDensity", m) -> None:
        """Warn where concrete queries ``m`` lie beyond what the discretisation serves within tol."""

    @abc.abstractmethod
    def values(self, density: "EvolvedDensity", m) -> Array:
        """``density`` (whose discretisation this is) at the flat offsets ``m`` (q, 2)."""

    @abc.abstractmethod
    def discretise(self, density: "EvolvedDensity") -> "AbstractSpectralMethod":
        """This method with every choice it leaves open made and verified for ``density``'s
        concrete values (each path's own module)."""

    @abc.abstractmethod
    def sized(self, size, extent) -> "AbstractSpectralMethod":
        """The method the string API's ``size=``/``extent=`` describe on this path."""

    # -- shared behaviour -----------------------------------------------------------------------
    def with_sizes(self, size, extent):
        if size is not None:
            integer(size, "size", 8)
        return self.sized(size, extent)

    def carried(self):
        """``(λ, rule)`` this method carries, ``(None, None)`` when none."""
        return self.regularisation, self.regularisation_rule

    def carrying(self, lam, rule: str | None, note: str | None):
        """This method carrying the Tikhonov λ chosen with it (None: none)."""
        return dataclasses.replace(self, regularisation=lam, regularisation_rule=rule, regularisation_note=note)

    def regularised(self, lobe, s_from, s_to, lam, rule, noise):
        """``(λ, method)``: the λ of the division — a number as given; a rule's choice
        (:mod:`._regularise`), reused from a method that carries one of that rule, else chosen
        here from concrete values (UnresolvedMethodError when traced) and carried by the
        returned method; None: the method's own λ, else 0."""
        own, own_rule = self.carried()
        if rule is None:
            if lam is not None:
                return lam, self
            return (jnp.asarray(0.0) if own is None else own), self
        if own is not None and own_rule == rule:
            return own, self
        if needs_data(lobe, s_to) and not is_concrete((lobe, s_from, s_to, noise)):
            raise unresolved_regularisation(rule)
        value, how = choose(lobe, s_from, s_to, rule, noise)
        value = jnp.asarray(value)
        return value, self.carrying(value, rule, how)

    def unresolved(self) -> UnresolvedMethodError:
        return UnresolvedMethodError(
            f"the {self.path} path's discretisation depends on parameter values, which are traced here (inside "
            "jax.jit, grad or vmap) and so unknown; brdfscale does not fall back to a default size. Resolve it "
            "outside the transformation from concrete values, `method = brdfscale.select(lobe, s_from, s_to, "
            "tol=...)`, and pass `method=method` inside (re-select when the parameters move far), or fix the "
            f"size yourself with {type(self).__name__}({self.size_argument}=...)."
        )

    def _discretised(self, density: "EvolvedDensity", given=None) -> "AbstractSpectralMethod":
        """:meth:`discretise`, carrying the λ this method carries — or ``given``, a nonzero λ
        passed as a number (recorded by :func:`brdfscale.select` as ``"given"``)."""
        chosen, how = self.carried()
        if chosen is None and given is not None and float(given) != 0:
            chosen, how = given, "given"
        resolved = self.discretise(density)
        return resolved if chosen is None else resolved.carrying(chosen, how, self.regularisation_note)

    def _density(self, lobe, s_from, s_to, tol, regularisation, rule, noise, check):
        lam, method = self.regularised(lobe, s_from, s_to, regularisation, rule, noise)
        return EvolvedDensity(lobe.shape, s_from, s_to, lam, method, tol, check), method

    def applicable(self, lobe, s_from, s_to) -> bool:
        return True

    def choose(self, lobe, s_from, s_to) -> AbstractMethod:
        return self

    def resolve(self, lobe, s_from, s_to, *, tol, regularisation, rule, noise, check):
        if not is_concrete((lobe, s_from, s_to)):
            raise self.unresolved()
        density, method = self._density(lobe, s_from, s_to, tol, regularisation, rule, noise, check)
        if not is_concrete(density):
            raise method.unresolved()
        return method._discretised(density, given=density.regularisation if rule is None else None)

    def evaluate(self, lobe, s_from, s_to, *, tol, regularisation, rule, noise, check) -> AbstractLobe:
        own = tol if self.tol is None else self.tol
        density, method = self._density(lobe, s_from, s_to, own, regularisation, rule, noise, check)
        if method.tol is None and is_concrete(density):
            resolved = method._discretised(density)
            density = density.with_discretisation(resolved, resolved.tol)
        elif not method.resolved:
            raise method.unresolved()
        return Lobe(density, lobe.amplitude)


class EvolvedDensity(AbstractSlopeDensity):
    """``g_to`` of seed Eq. 4.4: transform ``G_from S_from / S_to`` (regularised by λ).

    ``discretisation`` is a spectral method — :class:`~brdfscale.Radial` or
    :class:`~brdfscale.Grid` — with at least its node count or grid side fixed; it owns the
    inversion (``_radial.py``, ``_grid.py``), this class the exact transform; ``tol`` is
    the error relative to the peak that the evaluation honours: half of it for the spectral
    truncation (cut-off and extent), half for interpolation (tables), each verified by
    :func:`brdfscale.select` for concrete values.

    When both statistics are Gaussian (and λ = 0) the quotient ``S_from/S_to`` is evaluated
    as the single exponential ``exp(−½Wᵀ(Σ_from − Σ_to)W − iW·(mean_from − mean_to))``: the
    two transforms underflow separately long before their quotient is negligible (a narrow lobe
    between close scales was 9 % off at its peak when divided).
    """

    base: AbstractSlopeDensity
    s_from: AbstractSlopeDensity
    s_to: AbstractSlopeDensity
    regularisation: Float[Array, ""]
    discretisation: AbstractSpectralMethod | None  # None only for the probe's canonical copy (never evaluated)
    tol: float = eqx.field(static=True)
    isotropic: bool = eqx.field(static=True)
    check: bool = eqx.field(static=True)
    """Whether evaluations attach the existence check (|G| ≤ 1, no negative values) at run time."""
    gaussian_ratio: bool = eqx.field(static=True)

    _show_in_lobe = True  # a Lobe of this shape lists these items itself

    @property
    def _path(self) -> AbstractSpectralMethod:
        """The discretisation (set on every density that is evaluated; None only on the probe's copy)."""
        assert self.discretisation is not None
        return self.discretisation

    def _show_items(self):
        d = self._path
        items = [("base", self.base), ("s_from", self.s_from), ("s_to", self.s_to), ("path", d.path), *d.show_sizes()]
        return items + [("tol", self.tol), ("regularisation", self.regularisation)]

    def __init__(self, base, s_from, s_to, regularisation, discretisation, tol, check=True):
        self.base, self.s_from, self.s_to = base, s_from, s_to
        self.regularisation = jnp.asarray(regularisation)
        self.discretisation = discretisation
        self.tol = float(tol)
        self.isotropic = base.isotropic and s_from.isotropic and s_to.isotropic
        self.check = bool(check)
        lam = self.regularisation
        self.gaussian_ratio = (
            isinstance(s_from, Gaussian)
            and isinstance(s_to, Gaussian)
            and is_concrete(lam)
            and bool(np.all(np.asarray(lam) == 0))
        )

    @property
    def method(self) -> str:
        """``"radial"`` or ``"grid"``."""
        return self._path.path

    @property
    def size(self) -> int | None:
        """Gauss–Legendre nodes (radial) or grid side (grid)."""
        return self._path.resolution

    @property
    def extent(self) -> Float[Array, ""] | None:
        """The grid path's slope half-width as given (None: from the support radius; radial)."""
        return self._path.half_width

    def with_discretisation(self, discretisation, tol=None) -> "EvolvedDensity":
        return EvolvedDensity(
            self.base,
            self.s_from,
            self.s_to,
            self.regularisation,
            discretisation,
            self.tol if tol is None else tol,
            self.check,
        )

    # -- the exact transform -------------------------------------------------------------
    def _divide(self, numerator, denominator):
        """``N S*/(|S|² + λ²)`` written as ``N / (S + λ²/S*)`` so that a denormal S still
        divides exactly when λ = 0. Where S = 0: 0 if N = 0 or λ > 0, else ∞ (which the
        existence check then reports) — never 0/0."""
        lam2 = self.regularisation**2
        zero = denominator == 0
        safe = jnp.where(zero, 1.0, denominator)
        ratio = numerator / (safe + lam2 / jnp.conj(safe))
        at_zero = jnp.where((numerator == 0) | (lam2 > 0), 0.0, jnp.inf)
        return jnp.where(zero, at_zero, ratio)

    def _gaussians(self) -> tuple[Gaussian, Gaussian]:
        """``(s_from, s_to)`` where :attr:`gaussian_ratio` holds: both Gaussian by construction."""
        s_from, s_to = self.s_from, self.s_to
        assert isinstance(s_from, Gaussian) and isinstance(s_to, Gaussian)
        return s_from, s_to

    def _ratio(self, W, with_base=False):
        """``S_from/S_to`` of two Gaussians at W (..., 2), as one exponential (``with_base``: times
        the Gaussian lobe's transform, in the same exponent)."""
        s_from, s_to = self._gaussians()
        C = s_from.cov - s_to.cov
        mean = s_from.mean
        if s_to.mean is not None:
            mean = -s_to.mean if mean is None else mean - s_to.mean
        if with_base:
            base = self.base
            assert isinstance(base, Gaussian)  # with_base only where _gaussian_base holds
            C = C + base.cov
            if base.mean is not None:
                mean = base.mean if mean is None else mean + base.mean
        quad = jnp.einsum("...i,ij,...j->...", W, C, W)
        return shifted_cf(_exp_capped(-0.5 * quad), W, mean)

    @property
    def _gaussian_base(self) -> bool:
        """A Gaussian lobe between Gaussian statistics: the whole transform is one exponential.
        Going finer, the lobe's transform underflows where the growing quotient is still large
        (a Beckmann lobe of 1.73 between Beckmann 1 and 2, whose result is Beckmann 0.05: the
        product was 0 beyond |W| ≈ 31 and the forced spectral paths refused it as negative)."""
        return self.gaussian_ratio and isinstance(self.base, Gaussian)

    def _quotient(self, transform, W=None):
        """``G_from S_from / S_to`` from ``transform(density)`` of each factor (``W``: the
        frequencies, for the Gaussian quotient)."""
        if self._gaussian_base:
            return self._ratio(W, with_base=True)
        if self.gaussian_ratio:
            return transform(self.base) * self._ratio(W)
        numerator = transform(self.base) * transform(self.s_from)
        if isinstance(self.s_to, Delta) and self.s_to.mean is None:  # μ = ∞: nothing to divide
            return numerator
        return self._divide(numerator, transform(self.s_to))

    def cf(self, W):
        W = check_slopes(W, "W")
        return self._quotient(lambda density: density.cf(W), W)

    def cf_grid(self, grid):
        return self._quotient(lambda density: density.cf_grid(grid), grid.nodes() if self.gaussian_ratio else None)

    def cf_radial(self, k):
        k = jnp.asarray(k)
        if self._gaussian_base:
            s_from, s_to = self._gaussians()
            base = self.base
            assert isinstance(base, Gaussian)  # _gaussian_base
            return _exp_capped(-0.5 * k**2 * (base.cov[0, 0] + s_from.cov[0, 0] - s_to.cov[0, 0]))
        if self.gaussian_ratio:
            s_from, s_to = self._gaussians()
            return self.base.cf_radial(k) * _exp_capped(-0.5 * k**2 * (s_from.cov[0, 0] - s_to.cov[0, 0]))
        return jnp.real(self._divide(self.base.cf_radial(k) * self.s_from.cf_radial(k), self.s_to.cf_radial(k)))

    def shifted(self, offset):
        return EvolvedDensity(
            self.base.shifted(offset),
            self.s_from,
            self.s_to,
            self.regularisation,
            self.discretisation,
            self.tol,
            self.check,
        )

    def support_radius(self, tol):
        return self.base.support_radius(tol) + self.s_from.support_radius(tol)

    def _probe(self, k_lo=None):
        """|G| on rays at log-spaced frequencies: over nine decades scaled to the lobe's
        spatial extent (its support radius at 10⁻³ of the peak, or at ``tol`` when looser:
        the core, not a heavy tail's reach, which at a tight ``tol`` would pull the window
        below the frequencies the lobe has), or (``k_lo`` given) over the three decades above
        ``k_lo``.

        Only used for discretisation choices and the existence check, so no gradient flows
        through it (|G| is not differentiable where G = 0)."""
        canonical = self.with_discretisation(_PROBE_METHOD)  # sizes and cut-offs do not recompile the probe
        return _probe(jax.lax.stop_gradient(canonical), k_lo)

    def _probe_values(self, k_lo):
        dtype = jnp.result_type(*jax.tree_util.tree_leaves(self))
        if k_lo is None:
            R = jnp.maximum(self.support_radius(max(self.tol, CORE_TOL)), 1e-12)
            k = jnp.asarray(np.logspace(-2, 7, _PROBE_POINTS), dtype=dtype) / R
        else:
            k = k_lo * jnp.asarray(np.logspace(0, 3, _PROBE_POINTS_BEYOND), dtype=dtype)
        directions = 1 if self.isotropic else _PROBE_DIRECTIONS  # one ray says all for radial G
        phi = jnp.asarray(np.arange(directions) * np.pi / directions, dtype=dtype)
        W = k[:, None, None] * jnp.stack([jnp.cos(phi), jnp.sin(phi)], -1)[None]
        return k, jnp.abs(self.cf(W))

    def bandwidth(self, tol):
        """The frequency beyond which |G| stays below ``tol`` (the largest probe frequency
        when it does not fall that low in the probed window: :func:`brdfscale.select` reports
        that for concrete inputs)."""
        k, mag = self._probe()
        return cutoff(k, mag, tol)

    # -- inversion ------------------------------------------------------------------------
    def density(self, m):
        """``g_to(m)`` at any number of offsets, in blocks within the method's memory budget
        (:mod:`brdfscale._blocks`); within ``tol`` of the peak wherever the discretisation
        covers (module docstring)."""
        m = check_slopes(m, "m")
        self._path.check_queries(self, m)  # warns where the discretisation does not reach them
        return _density(self, m)

    def _density(self, m):
        return self._path.values(self, m.reshape(-1, 2)).reshape(m.shape[:-1])

    @property
    def _sign_check(self) -> bool:
        """The check that no value lies below −tol of the peak (with ``check``; not for μ = ∞,
        where nothing is divided and the lobe is a convolution of densities)."""
        plain = isinstance(self.s_to, Delta) and self.s_to.mean is None
        return self.check and self._path.sign_check and not plain

    # the spectral paths' inversions, as this density's own (the method owns each) ---------------
    def radial_coefficients(self):
        """``(k, c, peak, failed)`` of the radial path (:meth:`brdfscale.Radial.coefficients`)."""
        return self._path.coefficients(self)  # pyright: ignore[reportAttributeAccessIssue]

    def radial_table(self):
        """The lobe at the radii of the radial method's table (:class:`~brdfscale.RadialTable`)."""
        return self._path.table_values(self)  # pyright: ignore[reportAttributeAccessIssue]

    def grid_spacing(self):
        """Slope-grid spacing h and half-width a = N h / 2 of the grid path."""
        return self._path.spacing(self)  # pyright: ignore[reportAttributeAccessIssue]

    def frequency_grid(self, h):
        """The real-FFT frequencies of the grid path's ``size × size`` slope grid of spacing ``h``."""
        return self._path.frequency_grid(h)  # pyright: ignore[reportAttributeAccessIssue]

    def on_grid(self, oversample: int = 1):
        """``(u, values)``: nodes ``u`` (pN,) from −a to a − h/p and ``g_to`` on the pN × pN
        slope grid (rows u_y, columns u_x) by one real inverse FFT of the N × N spectrum,
        zero-padded by the factor ``p = oversample`` (grid path: :meth:`brdfscale.Grid.on_grid`)."""
        return self._path.on_grid(self, oversample)  # pyright: ignore[reportAttributeAccessIssue]


def _exp_capped(x):
    """``e^x`` with x capped below overflow: a growing Gaussian quotient (target wider than the
    source statistics) times a lobe transform that has underflowed to 0 is 0, not 0 · ∞; where
    the lobe has not underflowed the capped value still exceeds 1 by far (the existence check)."""
    cap = math.log(float(jnp.finfo(jnp.result_type(x)).max)) - 8
    return jnp.exp(jnp.minimum(x, cap))


def checked(value, failed, negative):
    """Attach the existence checks: ``|G| ≤ 1`` (``failed``) and no values below −tol of the
    peak (``negative``); None: nothing to check."""
    value = attach(value, failed, TRANSFORM_ABOVE_ONE)
    return attach(value, negative, NEGATIVE_LOBE)


_PROBE_METHOD = None  # the probe's canonical copy: sizes and cut-offs do not recompile host-side choices
_density = translated(eqx.filter_jit(lambda shape, m: shape._density(m)))
# compiled once each for the host-side choices (eager dispatch would compile every operation)
concrete_cutoff = eqx.filter_jit(lambda k, mag, tol: cutoff(k, mag, tol))
_concrete_support = eqx.filter_jit(lambda shape, tol: shape.support_radius(tol))
_concrete_cf_radial = eqx.filter_jit(lambda shape, k: shape.cf_radial(k))


def concrete_support(shape, tol):
    return _concrete_support(shape.with_discretisation(_PROBE_METHOD), tol)


def concrete_cf_radial(shape, k):
    return _concrete_cf_radial(shape.with_discretisation(_PROBE_METHOD), k)


_probe = eqx.filter_jit(lambda shape, k_lo: shape._probe_values(k_lo))


def cutoff(k, mag, tol):
    """The cut-off frequency K for an error ``tol`` relative to the lobe's peak: the larger of
    the first probe frequency past the last one where ``|G| > tol``, and the first beyond which
    the k-weighted tail is below ``tol`` of the whole,

        Σ_{k_i ≥ K} |G(k_i)| k_i² ≤ tol · Σ_i |G(k_i)| k_i²   (log-spaced k: k² d ln k = k dk),

    since truncating the inverse transform at K changes the density by at most
    ``(2π)⁻¹ ∫_K^∞ |G| k dk`` (radially; the largest |G| over the probe's rays otherwise),
    and ``(2π)⁻¹ ∫ |G| k dk`` is the peak of a lobe whose transform does not change sign — a
    slowly decaying transform (GGX's e^{−αk}) needs the tail criterion, a fast one the pointwise."""
    n = k.shape[0]
    above = jnp.any(mag > tol, axis=1)
    pointwise = jnp.minimum(jnp.max(jnp.where(above, jnp.arange(n), 0)) + 1, n - 1)
    weight = jnp.max(mag, axis=1) * k**2
    tail = jnp.cumsum(weight[::-1])[::-1]  # tail[i] = Σ_{j ≥ i} weight_j
    inside = tail <= tol * tail[0]
    by_tail = jnp.where(jnp.any(inside), jnp.argmax(inside), n - 1)
    return k[jnp.maximum(pointwise, by_tail)]


def radial_nodes(K: float, r_max: float, tol: float) -> int:
    """Gauss–Legendre nodes on [0, K] that integrate ``G(k) J0(k r) k`` to ``tol`` when the
    integrand's oscillation spans ``r_max`` in slope (the query radius plus the lobe's own
    extent, over which G oscillates): about ``K r_max/2`` oscillations' worth plus a margin,
    in multiples of 64. The
    margin grows as ``tol^{−1/5}`` below 1e-8: the rule converges algebraically on the
    ``k² ln k`` behaviour of K₀/K₁-type transforms (GGX, Student-t) at the origin (64 nodes
    leave ~5e-10 of the peak there; measured in tests/test_evolve.py)."""
    return int(64 * math.ceil(max(64.0, 0.6 * K * r_max + _margin(tol)) / 64))


def _margin(tol: float) -> int:
    return 64 * math.ceil(max(1e-8 / tol, 1.0) ** 0.2)


def radial_reach(K: float, nodes: int, tol: float) -> float:
    """The largest oscillation span (query radius plus the lobe's extent) that ``nodes``
    Gauss–Legendre nodes on [0, K] integrate to ``tol`` (the inverse of :func:`radial_nodes`)."""
    return max(0.0, (nodes - _margin(tol)) / (0.6 * K))


def probe_checks(density: EvolvedDensity, k, mag) -> None:
    """For concrete values: no transform above 1 (whatever tol), and every probe ray decays
    below tol/2 within the window (a lobe narrow along one axis decays late along it)."""
    if density.check and not isinstance(density.s_to, Delta) and bool(transform_exceeds_one(jnp.max(mag))):
        raise NoBRDFAtScaleError(TRANSFORM_ABOVE_ONE)
    if not bool(jnp.all(mag[-1] <= density.tol / 2)):
        raise InvalidInputError(
            f"tol={density.tol:g}: the evolved lobe's transform does not fall below tol/2 within nine decades "
            "of frequency above the lobe's width (a transform that decays this slowly, or a tol below the "
            "rounding of its evaluation); choose a larger tol. Towards a finer scale with tabulated or noisy input "
            "the unregularised quotient grows with frequency instead: pass regularisation='auto' (or a λ > 0)."
        )


def grid_size(density: EvolvedDensity, max_size: int, k=None, mag=None, truncation=None) -> tuple[int, float]:
    """Grid side that resolves ``density`` to the truncation error ``truncation`` (default
    ``tol/2``, the other half being interpolation's) in its cut-off and extent, and the
    truncation error honoured.

    A power of two, capped at ``max_size``. When the cap cannot meet the target (heavy tails,
    e.g. GGX's |m|⁻⁴, need grids of extent ∝ tol^{−1/4}) the target is relaxed by decades
    until the grid fits, and the error it can honour is returned; InvalidInputError when not
    even 1e-2 fits (a lobe far narrower along one axis than its extent along another).
    Needs concrete values (``k``, ``mag``: the density's probe, when already computed).
    """
    if k is None:
        k, mag = density._probe()
    tol = density.tol / 2 if truncation is None else truncation
    while True:
        K = float(concrete_cutoff(k, mag, tol))
        R = float(concrete_support(density, tol) if density.extent is None else density.extent)
        # spacing h = 2R/N must resolve K: π/h ≥ K  ⇒  N ≥ 2 R K / π
        need = max(64.0, 2 * R * K / math.pi)
        if need <= max_size:
            return int(2 ** math.ceil(math.log2(need))), tol
        if tol >= 1e-2:
            raise InvalidInputError(
                f"the grid path cannot resolve this lobe even to 1e-2: it needs {need:.3g} nodes per side (extent "
                f"{R:.3g}, bandwidth {K:.3g}), more than {max_size}. Pass a larger size= (memory ∝ size²), use "
                "method='radial' for radially symmetric inputs, or evolve the narrow and wide parts separately."
            )
        tol *= 10
