"""The evaluation steps a plan is made of, one per material (and path).

Each step holds the material's queries, deduplicated to the distinct (offset u, scale μ)
pairs present, and the discretisation the planner chose; calling it with the material
returns ``A · g_μ(u)`` at those pairs. All discretisation choices are frozen in the step
(static fields and constant arrays), so a step is a pure, jit-able and differentiable
function of the material's parameters.

* :class:`ClosedFormStep` — the closed-form evolution (Gaussian/δ/mixture algebra) at every
  query's own μ: exact.
* :class:`RadialStep` — radially symmetric inputs: the evolved transform ``G(k, μ_n)`` at
  Gauss–Legendre nodes on [0, K] for scale nodes ``μ_n``, times a cached Hankel kernel
  ``w_k k J₀(k r_j)/2π`` gives the lobe on a radius grid ``r_j`` (or directly at the query
  radii); queries are read off by cubic interpolation in (log μ, r).
* :class:`GridStep` — general inputs: the 2D-FFT grid path at scale nodes, cubic
  interpolation in (log μ, u_y, u_x).
* :class:`SO3Step` — anisotropic materials (:class:`AnisotropicMaterial`): per distinct
  (i, o) pair, the SO(3) transform of the lobe at μ0 (only the degrees and orders needed), the
  block evolution to the scale nodes, synthesis at the queries' global orientations.

Scale nodes are either the distinct μ of the queries (``exact_scales``: no interpolation in
μ) or uniform in log μ (cubic interpolation in log μ).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Complex, Float, Int

from .. import so3
from .._blocks import in_blocks
from .._evolve import AbstractMethod, ClosedForm, evolve, EvolvedDensity, Grid, Radial
from .._existence import attach, TRANSFORM_ABOVE_ONE, transform_exceeds_one
from .._interpolate import cubic_stencil, interpolate
from .._show import Shown
from ._description import AnisotropicMaterial, Material


# temporaries per query of cubic interpolation in d dimensions (4^d gathered values, indices and
# weights, float64): the blocks of brdfscale._blocks keep Plan.evaluate within its budget
_INTERPOLATION_BYTES = {d: 8 * (3 * 4**d + 8 * d) for d in (1, 2, 3)}


class ClosedFormStep(Shown, eqx.Module):
    """Closed-form evolution at each distinct scale, evaluated at its queries: exact."""

    u: Float[Array, "n 2"]
    scale: Int[Array, " n"]  # each query's index into ``mu``
    mu: Float[Array, " s"]  # the distinct scales

    def __call__(self, material: Material) -> Float[Array, " n"]:
        s_from = material.statistics(material.mu0)
        evolved = jax.vmap(lambda mu: evolve(material.lobe, s_from, material.statistics(mu), method=ClosedForm()))(
            self.mu
        )
        per_query = jax.tree_util.tree_map(lambda leaf: leaf[self.scale], evolved)
        return jax.vmap(lambda lobe, u: lobe.density(u))(per_query, self.u)


def _scale_position(log_mu, nodes, exact):
    """Index positions of the queries' log μ on the scale nodes."""
    if exact:
        return jnp.searchsorted(nodes, log_mu).astype(log_mu.dtype)
    if nodes.shape[0] == 1:
        return jnp.zeros_like(log_mu)
    return (log_mu - nodes[0]) / (nodes[1] - nodes[0])


def evolved_density(material: Material, mu, discretisation: AbstractMethod, tol: float) -> EvolvedDensity:
    """The material's lobe shape evolved from μ0 to μ (seed Eq. 4.4) on a spectral path
    (``discretisation``: a :class:`~brdfscale.Radial` or :class:`~brdfscale.Grid` with its size)."""
    return EvolvedDensity(
        material.lobe.shape,
        material.statistics(material.mu0),
        material.statistics(mu),
        material.regularisation,
        discretisation,
        tol,
    )


class RadialStep(Shown, eqx.Module):
    """Hankel path: ``g(r, μ_n) = Σ_k G(k_k, μ_n) · kernel[k, j]`` (module docstring).

    ``kernel`` is ``w_k k J₀(k r_j)/2π`` on the radius grid ``r_j = (j − 3) h_r`` (three mirror
    nodes below r = 0, so cubic stencils near 0 are centred), or at the queries' own radii
    (``direct``: one row per distinct (u, μ), no interpolation in r).
    """

    u: Float[Array, "n 2"]
    log_mu: Float[Array, " n"]
    nodes: Float[Array, " s"]  # log μ of the scale nodes
    k: Float[Array, " K"]
    kernel: Float[Array, "K r"]
    h_r: float = eqx.field(static=True)
    exact_scales: bool = eqx.field(static=True)
    direct: bool = eqx.field(static=True)
    tol: float = eqx.field(static=True)

    def transforms(self, material: Material) -> Float[Array, "s K"]:
        """``G(k, μ_n)`` for every scale node, with the existence check |G| ≤ 1."""
        size = self.k.shape[0]
        G = jax.vmap(lambda t: evolved_density(material, jnp.exp(t), Radial(nodes=size), self.tol).cf_radial(self.k))(
            self.nodes
        )
        return attach(G, transform_exceeds_one(jnp.max(jnp.abs(G))), TRANSFORM_ABOVE_ONE)

    def table(self, material: Material) -> Float[Array, "s r"]:
        """The lobe shape ``g`` on (scale nodes × radius grid)."""
        return self.transforms(material) @ self.kernel

    def __call__(self, material: Material) -> Float[Array, " n"]:
        s = _scale_position(self.log_mu, self.nodes, self.exact_scales)
        if self.direct:
            G = self.transforms(material)
            return jnp.sum(G[s.astype(int)] * self.kernel.T, axis=-1) * material.lobe.amplitude
        r = jnp.linalg.norm(self.u, axis=-1) / self.h_r + 3
        table = self.table(material)
        values = in_blocks(lambda p: interpolate(table, p), jnp.stack([s, r], -1), _INTERPOLATION_BYTES[2])
        return values * material.lobe.amplitude


class GridStep(Shown, eqx.Module):
    """2D-FFT grid path at each scale node (side ``size``).

    Table mode: the lobe on the grid by one inverse FFT per scale node, cubic interpolation in
    (log μ, u_y, u_x); offsets outside the grid's half-width ``a`` (where the lobe is below
    ``tol`` of its peak by the statistics' support radius) evaluate to 0. Direct mode (few
    queries, exact scales): the same inverse DFT summed at the query offsets, with the
    frequency grid and the per-query phase factors ``e^{iW·u}`` frozen at planning time.
    """

    u: Float[Array, "n 2"]
    log_mu: Float[Array, " n"]
    nodes: Float[Array, " s"]
    phases: tuple[Array, Array] | None  # direct mode: e^{i u_y W_y} (n, N), e^{i u_x W_x} (n, N/2+1)
    frequencies: Float[Array, "N N/2+1 2"] | None
    size: int = eqx.field(static=True)
    exact_scales: bool = eqx.field(static=True)
    tol: float = eqx.field(static=True)

    def densities(self, material: Material, mu):
        return evolved_density(material, mu, Grid(size=self.size), self.tol)

    def table(self, material: Material) -> Float[Array, "s N N"]:
        """The lobe shape on (scale nodes × u_y × u_x) grids."""
        return jax.vmap(lambda t: self.densities(material, jnp.exp(t)).on_grid()[1])(self.nodes)

    def __call__(self, material: Material) -> Float[Array, " n"]:
        s = _scale_position(self.log_mu, self.nodes, self.exact_scales)
        if self.phases is not None:
            return self._direct(material, s.astype(int)) * material.lobe.amplitude
        h, a = self.densities(material, jnp.exp(self.nodes[0])).grid_spacing()
        pos = (self.u[:, ::-1] + a) / h  # (y, x) index positions
        inside = jnp.all((pos >= 0) & (pos <= self.size - 1), axis=-1)
        table = self.table(material)
        values = in_blocks(
            lambda p: interpolate(table, p), jnp.concatenate([s[:, None], pos], -1), _INTERPOLATION_BYTES[3]
        )
        return jnp.where(inside, values, 0.0) * material.lobe.amplitude

    def _direct(self, material, s):
        W, phases = self.frequencies, self.phases
        assert W is not None and phases is not None  # direct mode: both frozen at planning time
        G = jax.vmap(lambda t: self.densities(material, jnp.exp(t)).cf(W))(self.nodes)  # (s, N, N/2+1)
        G = attach(G, transform_exceeds_one(jnp.max(jnp.abs(G))), TRANSFORM_ABOVE_ONE)
        nx = W.shape[1]
        half = jnp.where((jnp.arange(nx) == 0) | (2 * jnp.arange(nx) == self.size), 1.0, 2.0)
        ey, ex = phases
        total = jnp.einsum("qy,syx,qx->qs", ey, G * half, ex)
        dW = W[0, 1, 0] - W[0, 0, 0]
        return jnp.real(jnp.take_along_axis(total, s[:, None], axis=1)[:, 0]) * dW**2 / (2 * jnp.pi) ** 2


class SO3Step(Shown, eqx.Module):
    """SO(3) path (seed §5): ``ρ(i, o, Γ∞, μ) = Σ_J Σ_{MM'} R^J_{MM'}(μ) D^J_{MM'}(Γ∞)``.

    Per distinct (i, o) pair: the lobe's samples on the Kostelec–Rockmore grid of band limit
    ``sample_band_limit`` (≥ ``band_limit``, so that the μ0 lobe's content above the band
    limit does not alias into the kept degrees), :func:`brdfscale.so3.forward` restricted to
    the orders needed (rows |M| ≤ ``rows``, twist columns |M'| ≤ ``lobe_columns``), kept for
    degrees J < ``band_limit``. Evolution to each scale node by the diffusion propagator
    ``exp(−(τ(μ0) − τ(μ)) G^J)``: elementwise on the twist orders when ``G`` is diagonal
    (``D_x = D_y``: columns do not mix), else the blocks of
    :func:`brdfscale.so3.diffusion_operator` from ``lobe_columns`` to ``columns``. Then
    :func:`brdfscale.so3.synthesize` at the pair's query orientations (Euler angles, padded to a
    common count per pair) and, between scale nodes, cubic interpolation in log μ.
    """

    pairs: Float[Array, "P 2 3"]  # (i, o) per distinct pair
    angles: Float[Array, "P q 3"]  # Euler angles of each pair's distinct orientations (padded)
    key_pair: Int[Array, " n"]  # each distinct (pair, Γ∞, μ) key's pair
    key_slot: Int[Array, " n"]  # … and its orientation's slot in ``angles``
    log_mu: Float[Array, " n"]
    nodes: Float[Array, " s"]
    band_limit: int = eqx.field(static=True)
    sample_band_limit: int = eqx.field(static=True)
    rows: int = eqx.field(static=True)
    lobe_columns: int = eqx.field(static=True)
    columns: int = eqx.field(static=True)
    diagonal: bool = eqx.field(static=True)
    exact_scales: bool = eqx.field(static=True)

    def lobe_coefficients(self, material: AnisotropicMaterial) -> Complex[Array, "P B rows lobe_columns"]:
        """SO(3) coefficients of ``Γ ↦ ρ(i, o, Γ)`` at μ0 for every pair (degrees J < band limit B; ``rows``
        = 2L+1 orders M, ``lobe_columns`` = 2N0+1 orders M')."""

        def one(io):
            samples = material.lobe.samples(io[0], io[1], self.sample_band_limit)
            return so3.forward(samples, m_max=self.rows, n_max=self.lobe_columns)[: self.band_limit]

        return jax.lax.map(one, self.pairs)

    def evolved(self, material: AnisotropicMaterial, R0) -> Complex[Array, "P s B rows columns"]:
        """``R^J(μ_n) = R^J(μ0) exp(−(τ(μ0) − τ(μ_n)) G^J)`` for every pair and scale node, from
        the lobe's coefficients ``R0`` (:meth:`lobe_coefficients`)."""
        B, n0, n1 = self.band_limit, self.lobe_columns, self.columns
        dtau = material.tau(material.mu0) - material.tau(jnp.exp(self.nodes))  # (s,)
        if self.diagonal:
            g = jnp.diagonal(so3.diffusion_generator(B, material.law.D), axis1=-2, axis2=-1)[:, B - 1 - n1 : B + n1]
            return R0[:, None] * jnp.exp(-dtau[:, None, None] * g)[None, :, :, None, :]
        E = jax.vmap(lambda t: so3.diffusion_operator(B, material.law.D, t))(dtau)
        E = E[:, :, B - 1 - n0 : B + n0, B - 1 - n1 : B + n1].astype(R0.dtype)
        return jnp.einsum("pjab,sjbc->psjac", R0, E)

    def node_values(self, material: AnisotropicMaterial, R0) -> Float[Array, "n s"]:
        """ρ at every key's orientation, at every scale node."""
        values = jax.lax.map(
            lambda args: jnp.real(so3.synthesize(args[0], args[1][:, 0], args[1][:, 1], args[1][:, 2])),
            (self.evolved(material, R0), self.angles),
        )  # (P, s, q)
        return values[self.key_pair, :, self.key_slot]

    def __call__(self, material: AnisotropicMaterial) -> Float[Array, " n"]:
        per_key = self.node_values(material, self.lobe_coefficients(material))
        s = _scale_position(self.log_mu, self.nodes, self.exact_scales)
        if self.exact_scales or self.nodes.shape[0] < 4:
            return jnp.take_along_axis(per_key, jnp.round(s).astype(int)[:, None], axis=1)[:, 0]
        base, w = cubic_stencil(s, self.nodes.shape[0])
        return jnp.sum(jnp.take_along_axis(per_key, base[:, None] + jnp.arange(4), axis=1) * w, axis=1)


Step = ClosedFormStep | RadialStep | GridStep | SO3Step


class MaterialPlan(Shown, eqx.Module):
    """One material's part of a plan: which queries, through which step, and what it predicts."""

    material: int = eqx.field(static=True)
    rows: Int[Array, " q"]  # the queries (indices into the scene's list) this step serves
    inverse: Int[Array, " q"]  # each query's distinct (u, μ) pair
    factor: Float[Array, " q"]  # F(i, o), the mirror-microfacet factor (1 on the SO(3) path: ρ includes it)
    step: Step
    path: str = eqx.field(static=True)
    reason: str = eqx.field(static=True)
    predicted_error: float = eqx.field(static=True)
    predicted_cost: float = eqx.field(static=True)  # relative units (:mod:`._cost`)
    details: str = eqx.field(static=True)

    @property
    def queries(self) -> int:
        """How many of the scene's queries this part serves."""
        return self.rows.shape[0]

    def _show_items(self):
        return [
            ("material", self.material),
            ("path", self.path),
            ("queries", self.queries),
            ("predicted_error", self.predicted_error),
            ("predicted_cost", self.predicted_cost),
        ]

    def __call__(self, material: Material | AnisotropicMaterial) -> Float[Array, " q"]:
        # the planner pairs SO3Step with an AnisotropicMaterial and the other steps with a Material
        return self.step(material)[self.inverse] * self.factor  # pyright: ignore[reportArgumentType]
