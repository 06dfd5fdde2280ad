"""The radial (Hankel) path: ``g(r) = (2π)⁻¹ ∫_0^K G(k) J₀(kr) k dk`` for radially symmetric inputs.

:class:`Radial` owns the whole path (the pattern of lineax's solvers): whether it applies
(lobe and both statistics radially symmetric), its resolution from concrete values
(:meth:`Radial.discretise`, what :func:`brdfscale.select` returns), its evaluation at query
offsets (:meth:`Radial.values`) and :meth:`Radial.explain`. Every choice is verified on the
values it is made for:

* the cut-off K bounds the truncation error (tail criterion of :func:`._spectral.cutoff`) by
  tol/2 of the peak;
* the node count integrates ``G(k) J₀(kr) k`` to that over every radius up to the support
  radius R (beyond it the lobe is below tol/2; :func:`._spectral.radial_nodes`);
* the table of radii — uniform in ``t = asinh(K r)`` (uniform near 0 at spacing ``h/K``,
  geometric in the tail) — is refined until 8-point Lagrange interpolation between its
  nodes, checked at every midpoint against the quadrature itself, is within tol/2;
* the existence check for those values: ``|G| ≤ 1`` on the probe and no evolved value below
  −tol of the peak (table radii and midpoints).

A resolved method is verified for the parameters it was selected with; reused with other values
(a fit's iterations) it honours its tolerance while the lobe's width and bandwidth stay
similar — re-select when they move far.
"""

import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.special
from jaxtyping import Array, Float

from .._blocks import DEFAULT_BUDGET, in_blocks
from .._errors import MethodNotApplicableError, NoBRDFAtScaleError
from .._existence import negative_beyond, NEGATIVE_LOBE, transform_exceeds_one
from .._interpolate import interpolate, lagrange_stencil
from .._quadrature import gauss_legendre
from .._show import Shown
from .._slopes import safe_norm
from .._special import j0, J_TEMPORARIES
from .._validation import is_concrete
from ..stats import Delta
from ._method import (
    caller_stacklevel,
    check_budget,
    check_count,
    check_positive,
    lambda_note,
    number,
    optional_array,
    tol_note,
)
from ._spectral import (
    AbstractSpectralMethod,
    checked,
    concrete_cf_radial,
    concrete_cutoff,
    concrete_support,
    cutoff,
    probe_checks,
    radial_nodes,
    radial_reach,
)


MAX_RADIAL_NODES = 8192
"""The most Gauss–Legendre nodes chosen automatically (an explicit ``nodes`` may exceed it;
SciPy builds the rule in O(n²): 1.9 s at 8192, 7.5 s at 16384, once per size)."""
MAX_SIGN_CHECK_NODES = 2**20
"""The most Gauss–Legendre nodes the existence check uses where the method's own are fewer."""
MAX_TABLE_ENTRIES = 2**23
"""The largest radial table kernel (nodes × radii: 64 MiB in float64)."""
TABLE_POINTS = 8
"""Lagrange points of the radial table's interpolation (error ∝ h⁸: 512 radii reach 4e-11 of
the peak for README's lobe, where cubic stencils need 4096)."""


class RadialTable(Shown, eqx.Module):
    """The radial path's table: the lobe at radii ``r_j = c sinh((j − 3) h)`` (three mirror
    nodes below r = 0, where g is even, and five beyond the last radius served), as
    ``kernel[:, j] = J₀(k_i r_j)`` on the method's Gauss–Legendre frequencies ``k_i``, read
    off by ``points``-point Lagrange interpolation in ``t = asinh(r/c)``. Uniform in r near 0
    (spacing ``c h``), geometric beyond ``c``: heavy tails need few radii."""

    # the floats are array leaves, not static fields: a new value must not recompile the evaluation
    kernel: Float[Array, "nodes radii"]
    scale: Float[Array, ""] = eqx.field(converter=jnp.asarray)  # c
    step: Float[Array, ""] = eqx.field(converter=jnp.asarray)  # h
    radius: Float[Array, ""] = eqx.field(
        converter=jnp.asarray
    )  # the last radius served; beyond it g < tol/2 of its peak
    error: Float[Array, ""] = eqx.field(converter=jnp.asarray)  # verified interpolation error, relative to the peak
    points: int = eqx.field(static=True, default=8)

    @property
    def count(self) -> int:
        return self.kernel.shape[1]


class Radial(AbstractSpectralMethod):
    """The radial (Hankel) path: ``g(r) = (2π)⁻¹ ∫_0^K G(k) J₀(kr) k dk``.

    Args:
        nodes: Gauss–Legendre nodes on [0, K]; ``None`` for :func:`brdfscale.select` to choose.
        cutoff: the frequency cut-off K; ``None``: chosen at run time from the transform's
            probe (truncation below ``tol/2`` of the peak; traced values allowed).
        table: a verified table of radii (built by :func:`brdfscale.select`); ``None``:
            evaluate at the queries themselves.
        tol: the error, relative to the lobe's peak, the discretisation honours (set by
            :func:`brdfscale.select`).
        budget: bytes of temporaries an evaluation may hold at once (default 256 MiB): queries
            are evaluated in blocks that fit it, so any number of offsets can be asked for.
    """

    nodes: int | None = eqx.field(static=True, default=None)
    cutoff: Float[Array, ""] | None = eqx.field(default=None, converter=optional_array)
    table: RadialTable | None = None
    tol: float | None = eqx.field(static=True, default=None)
    budget: int = eqx.field(static=True, default=DEFAULT_BUDGET)
    sign_check: bool = eqx.field(static=True, default=True)
    """Whether evaluations refuse values below −tol of the peak (off where a caller's explicit
    nodes are too few for tol: their ringing is no evidence about existence)."""
    regularisation: Float[Array, ""] | None = eqx.field(default=None, converter=optional_array)
    """The Tikhonov λ chosen with the discretisation (:func:`brdfscale.select` with a rule or a
    λ; ``evolve(..., method=m)`` uses it unless given another); None: none chosen."""
    regularisation_rule: str | None = eqx.field(static=True, default=None)
    """How it was chosen (``"gcv"``, ``"discrepancy"``, ``"l_curve"``; ``"given"`` for a number)."""
    regularisation_note: str | None = eqx.field(static=True, default=None)
    dtype: str | None = eqx.field(static=True, default=None)
    """The floating dtype of the evaluation it was resolved for (set by :func:`brdfscale.select`;
    ``explain()`` states the error that dtype can honour)."""

    size_argument = "nodes"

    def __check_init__(self):
        check_budget(self.budget)
        check_count("Radial(nodes=...)", self.nodes, 8)
        check_positive("Radial(cutoff=...)", self.cutoff, "a positive frequency")

    @property
    def resolution(self) -> int | None:
        return self.nodes

    @property
    def _resolved_nodes(self) -> int:
        """The node count of a method that evaluates: always resolved (``evaluate`` raises
        :meth:`unresolved` first; the planner's steps fix it)."""
        assert self.nodes is not None
        return self.nodes

    def explain(self) -> str:
        if self.nodes is None:
            return "radial (Hankel) path, not yet resolved"
        cut = "K from the run-time probe" if self.cutoff is None else f"K = {number(self.cutoff):.4g}"
        if self.table is None:
            layout = "evaluated at the query radii"
        else:
            t = self.table
            layout = (
                f"table of {t.count} radii to r = {number(t.radius):.3g} (uniform in asinh(r/{number(t.scale):.3g}), "
                f"{t.points}-point Lagrange; verified error {number(t.error):.2g} of the peak), direct at the queries "
                "when they are few"
            )
        return (
            f"radial (Hankel) path: {self.nodes} Gauss–Legendre nodes, {cut}; {layout}"
            f"{tol_note(self.tol, self.dtype)}{lambda_note(self)}"
        )

    # -- which inputs -----------------------------------------------------------------------------
    def applicable(self, lobe, s_from, s_to) -> bool:
        return lobe.shape.isotropic and s_from.isotropic and s_to.isotropic

    def choose(self, lobe, s_from, s_to):
        if not self.applicable(lobe, s_from, s_to):
            raise MethodNotApplicableError(
                "method='radial' needs a radially symmetric lobe and statistics (isotropic, centred); "
                "use method='grid' for anisotropic, shifted, skewed or tabulated inputs."
            )
        return self

    def sized(self, size, extent):
        return self if size is None else Radial(nodes=int(size))

    # -- the Hankel kernel ------------------------------------------------------------------------
    @staticmethod
    def frequencies(K: float, nodes: int):
        """``(k, w)``: the Gauss–Legendre frequencies on [0, K] and their weights (NumPy)."""
        x, w = gauss_legendre(nodes)
        return 0.5 * (x + 1) * K, 0.5 * K * w

    @staticmethod
    def kernel(K: float, nodes: int, r):
        """``(k, w_k k J₀(k r_j)/2π)``: the frequencies and the Hankel kernel (nodes × radii)
        with which ``g(r_j) = Σ_k G(k) · kernel[k, j]`` (NumPy, SciPy's J₀)."""
        k, wk = Radial.frequencies(K, nodes)
        return k, (wk * k)[:, None] * scipy.special.j0(k[:, None] * np.asarray(r)[None, :]) / (2 * np.pi)

    # -- evaluation -------------------------------------------------------------------------------
    def coefficients(self, density):
        """``(k, c, peak, failed)``: the Gauss–Legendre frequencies on [0, K], the weights
        ``c_k = w_k k G(k)/2π`` (so ``g(r) = Σ c_k J₀(k r)``), the bound ``Σ|c_k| ≥ max g``,
        and the existence predicate (None without the check)."""
        divided = density.check and not isinstance(density.s_to, Delta)
        if self.cutoff is None or divided:
            k_probe, mag = density._probe()
        dtype = jnp.result_type(*jax.tree_util.tree_leaves(density.base), float)
        K = cutoff(k_probe, mag, density.tol / 2) if self.cutoff is None else jnp.asarray(self.cutoff, dtype)
        x, w = gauss_legendre(self._resolved_nodes)
        k = (0.5 * (jnp.asarray(x, dtype) + 1)) * K
        G = density.cf_radial(k)
        c = 0.5 * K * jnp.asarray(w, dtype) * k * G / (2 * jnp.pi)
        failed = None
        if divided:
            failed = transform_exceeds_one(jnp.maximum(jnp.max(mag), jnp.max(jnp.abs(jax.lax.stop_gradient(G)))))
        return k, c, jnp.sum(jnp.abs(jax.lax.stop_gradient(c))), failed

    def table_values(self, density):
        """The lobe at the radii of the method's table (:class:`RadialTable`)."""
        table = self.table
        assert table is not None  # called where the method carries its verified table
        _, c, _, failed = self.coefficients(density)
        values = c @ table.kernel.astype(c.dtype)
        return values, failed

    def values(self, density, m):
        r = safe_norm(m)
        q = r.shape[0]
        size = jnp.dtype(r.dtype).itemsize
        if self.table is not None and q > max(16, self.table.count // 64):
            values, failed = self.table_values(density)
            t = self.table
            negative = negative_beyond(values, jnp.max(values), density.tol) if density._sign_check else None

            scale, step, radius = (jnp.asarray(x, r.dtype) for x in (t.scale, t.step, t.radius))

            def read(rows):
                pos = jnp.arcsinh(rows / scale) / step + 3
                return jnp.where(rows <= radius, interpolate(values, pos[:, None], points=t.points), 0.0)

            out = in_blocks(read, r, (4 + 3 * t.points) * size, self.budget)
        else:
            k, c, peak, failed = self.coefficients(density)

            def direct(rows):
                return jnp.sum(c * j0(rows[:, None] * k), axis=-1)

            # J₀ holds a few (rows × nodes) arrays at once (brdfscale._special.J_TEMPORARIES)
            out = in_blocks(direct, r, k.shape[0] * (J_TEMPORARIES + 4) * size, self.budget)
            negative = negative_beyond(out, peak, density.tol) if density._sign_check else None
        return checked(out, failed, negative)

    def check_queries(self, density, m) -> None:
        if self.cutoff is not None and m.size and is_concrete((density, m)):
            # nodes enough for the largest queried radius (J₀(k r) oscillates over it, G over the lobe's extent)
            r_max = float(np.max(np.linalg.norm(np.asarray(m), axis=-1)))
            R = float(concrete_support(density, density.tol / 2))
            reach = min(r_max, R) + R
            n = radial_nodes(float(self.cutoff), reach, density.tol / 2)
            if n > self._resolved_nodes:
                warnings.warn(
                    f"queries at offsets up to {r_max:.3g} need {n} Gauss–Legendre nodes for tol={density.tol:g}; "
                    f"this lobe has {self.nodes} (evolve(..., size=...) raises it): errors there may exceed tol.",
                    stacklevel=caller_stacklevel(),
                )

    # -- resolution (module docstring) ------------------------------------------------------------
    def discretise(self, density) -> "Radial":
        k, mag = density._probe()
        probe_checks(density, k, mag)
        half = density.tol / 2
        K = float(self.cutoff) if self.cutoff is not None else float(concrete_cutoff(k, mag, half))
        R = float(concrete_support(density, half))
        needed = radial_nodes(K, 2 * R, half)
        nodes = self.nodes if self.nodes is not None else min(MAX_RADIAL_NODES, needed)
        sign_check = self.sign_check and nodes >= needed
        density = density.with_discretisation(Radial(nodes=nodes, cutoff=K, sign_check=sign_check))
        if density.check and not sign_check and needed <= MAX_SIGN_CHECK_NODES:
            _sign_check(density, needed, K, R)  # the existence check with the nodes it needs
        table = _table(density, nodes, K, R, half)
        dtype = jnp.dtype(jnp.result_type(*jax.tree_util.tree_leaves(density.base), float)).name
        return Radial(
            nodes=nodes, cutoff=K, table=table, tol=density.tol, budget=self.budget, sign_check=sign_check, dtype=dtype
        )


def _sign_check(density, nodes, K, R, radii=128):
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
    return np.concatenate([c @ scipy.special.j0(np.outer(k, r[i : i + per])) for i in range(0, len(r), per)])


def _table(density, nodes, K, R, half) -> RadialTable | None:
    """A table of radii out to R whose 8-point Lagrange interpolation is verified within
    ``half`` of the peak at every midpoint, and the existence check on its values (None when
    the nodes do not reach R — queries are then evaluated directly — or no table fits
    MAX_TABLE_ENTRIES)."""
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
