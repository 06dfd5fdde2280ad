"""The planner: from a scene's queries and error target to the cheapest adequate evaluation.

Per material, on the distinct (offset u = m_s − m∞, scale μ) pairs its queries present:

1. **Path** — the method object's own choice, as :func:`brdfscale.evolve` makes it
   (``as_method(method).choose(lobe, s_from, s_to)``, :mod:`brdfscale._evolve`): closed form
   (Gaussian/δ/mixture algebra; exact) when the lobe and statistics allow it; otherwise the
   radial Hankel path when everything is radially symmetric; otherwise the 2D-FFT grid path.
   The SO(3) path for an :class:`AnisotropicMaterial`, whose BRDF depends on the facet's twist
   (planned in :mod:`._so3_planner`). ``method=`` forces one; the chosen path's name selects
   the planning procedure below.
2. **Error budget** — the target ``tol`` (relative to the lobe's peak at each scale) is split
   into three quarters: spectral truncation (the frequency cut-off K or the grid's extent),
   interpolation in u (or r), interpolation in log μ. The last quarter is margin.
3. **Sizes from a-priori bounds** — radial: K from the truncation bound
   ``(2π)⁻¹ ∫_K^∞ |G| k dk ≤ (tol/4) g(0)`` (the library's ``cutoff``, the one
   :func:`brdfscale.select` uses, at each probed scale), Gauss–Legendre nodes from K and the largest queried radius
   (``radial_nodes``, the radial path's) and the Hankel kernel of :meth:`brdfscale.Radial.kernel`,
   and the radius spacing from the cubic-interpolation bound
   ``|error| ≤ (9/16)/4! · h⁴ max|g⁗|`` with ``max|g⁗| ≤ (2π)⁻¹ ∫|G| k⁵ dk``; grid: the side
   from the bandwidth and support radius (``grid_size`` of :mod:`brdfscale._evolve`, as
   :func:`brdfscale.select` uses it),
   doubled until cubic interpolation between its nodes is within budget (checked on the
   doubled grid, whose odd nodes are the midpoints).
4. **Scales** — the distinct μ present are used as they are when there are few; otherwise
   nodes uniform in log μ, refined until cubic interpolation in log μ, checked against exact
   tables at the midpoints between nodes, is within budget.
5. **Cost** — radial: direct evaluation at the query radii (a cached per-query J₀ kernel)
   versus a radius table plus interpolation, whichever the cost model (:mod:`._cost`,
   relative units) predicts cheaper; likewise the grid's direct DFT sums versus FFT tables.

Reusable pieces (Gauss–Legendre rules, J₀ kernels, the grids' frequency sets) are computed
once at planning time and frozen into the plan.
"""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InvalidInputError, MethodNotApplicableError, NoBRDFAtScaleError
from .._evolve import (
    as_method,
    CORE_TOL,
    cutoff,
    evolve,
    grid_size,
    MAX_GRID,
    Radial,
    radial_nodes,
)
from .._existence import message_of
from .._interpolate import interpolate
from ..geometry import half_slope, microfacet_factor
from . import _cost
from ._description import AnisotropicMaterial, Material, Scene
from ._plan import Plan
from ._scales import in_chunks, scale_nodes
from ._so3_planner import plan_so3
from ._steps import ClosedFormStep, evolved_density, GridStep, MaterialPlan, RadialStep


_METHODS = ("auto", "closed_form", "radial", "grid", "so3")  # the evolution methods' names, and the SO(3) path
_CUBIC_CONSTANT = 0.5625 / 24  # max |s(s−1)(s−2)(s−3)|/4! on the middle interval
_MAX_GRID = MAX_GRID
_DIRECT_MEMORY = 2e7  # largest (distinct queries × nodes) kernel kept for direct evaluation
_TABLE_OVERSAMPLING = 4  # a grid table needs about this many times the Nyquist side
_CHUNK = 64  # scales (and frequencies) per planning-time evaluation of radial transforms
_GRID_CHUNK_NODES = 64 * 256 * 256  # grid nodes per planning-time evaluation of grid tables


def plan(scene: Scene, method: str = "auto") -> Plan:
    """Plan the evaluation of ``scene`` (module docstring). Needs concrete values.

    Args:
        scene: materials, queries and the error target (:class:`Scene`).
        method: ``"auto"``, or force ``"closed_form"``, ``"radial"`` or ``"grid"`` for every
            (slope-space) material, or ``"so3"`` (every material an :class:`AnisotropicMaterial`).

    Returns:
        A :class:`Plan`; ``plan.evaluate()`` runs it (jit-compiled, differentiable in the
        materials' parameters), ``plan.explain()`` says what it computes and why.

    Raises:
        MethodNotApplicableError: a forced method does not apply to a material.
        NoBRDFAtScaleError: a material has no BRDF at a queried scale.
    """
    if not isinstance(scene, Scene):
        raise InvalidInputError(f"scene must be a brdfscale.scene.Scene; got {type(scene).__name__}.")
    if method not in _METHODS:
        raise InvalidInputError(f"method must be one of {_METHODS}; got {method!r}.")
    q = scene.queries
    u, factor = (np.asarray(a) for a in _geometry(q.i, q.o, q.m_inf))
    log_mu = np.log(np.asarray(q.mu))
    index = np.asarray(q.material)
    parts = []
    for m in np.unique(index):
        rows = np.flatnonzero(index == m)
        material = scene.materials[m]
        if isinstance(material, AnisotropicMaterial):
            if method not in ("auto", "so3"):
                raise MethodNotApplicableError(
                    f"material {m} is an AnisotropicMaterial (a BRDF of the facet's orientation on SO(3)): only "
                    f"method='so3' or 'auto' applies; got {method!r}."
                )
            inverse, planned = plan_so3(
                material,
                np.asarray(q.i)[rows],
                np.asarray(q.o)[rows],
                np.asarray(q.euler_angles())[rows],
                log_mu[rows],
                scene.tol,
            )
            factor_rows = np.ones(len(rows))
        else:
            if method == "so3":
                raise MethodNotApplicableError(
                    f"method='so3' needs an AnisotropicMaterial (a BRDF of the facet's orientation); material {m} "
                    "is a slope-space Material."
                )
            keys, inverse = np.unique(np.column_stack([u[rows], log_mu[rows]]), axis=0, return_inverse=True)
            planned = _plan_material(material, keys[:, :2], keys[:, 2], scene.tol, method)
            factor_rows = factor[rows]
        parts.append(
            MaterialPlan(int(m), jnp.asarray(rows), jnp.asarray(inverse.ravel()), jnp.asarray(factor_rows), *planned)
        )
    return Plan(scene.materials, tuple(parts), len(q), scene.tol, scene.pixels, scene.resolution)


def _plan_material(material: Material, u, log_mu, tol, method):
    mus = np.exp(log_mu)
    s_from = material.statistics(material.mu0)
    # the path as brdfscale.evolve and select choose it (structure only; MethodNotApplicableError
    # when a forced one does not apply)
    path = as_method(method).choose(material.lobe, s_from, material.statistics(mus.min()))
    try:
        return _PLANNERS[path.path](material, path, u, log_mu, tol)
    except (eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError) as err:  # the message inside JAX's traceback
        message = message_of(err)
        if message is None:
            raise
        raise NoBRDFAtScaleError(f"{message} (scales μ in [{mus.min():.4g}, {mus.max():.4g}])") from None


# -- closed form ----------------------------------------------------------------------------
def _plan_closed_form(material, path, u, log_mu, tol):
    mus = np.exp(log_mu)
    s_from = material.statistics(material.mu0)
    for mu in (mus.min(), mus.max()):  # existence at the ends (NoBRDFAtScaleError)
        evolve(material.lobe, s_from, material.statistics(mu), method=path)
    distinct, scale = np.unique(log_mu, return_inverse=True)
    n = len(mus)
    step = ClosedFormStep(jnp.asarray(u), jnp.asarray(scale.ravel()), jnp.asarray(np.exp(distinct)))
    return (
        step,
        path.path,
        "the lobe and statistics have a closed-form evolution (exact)",
        0.0,
        _cost.units(8 * (n + len(distinct)), 40 * n),
        f"{len(distinct)} distinct scales evolved exactly, {n} offsets evaluated",
    )


# -- radial ---------------------------------------------------------------------------------
@functools.lru_cache(maxsize=32)
def _hankel_kernel(K: float, n_k: int, radii: tuple | None, h_r: float, n_r: int):
    """The radial path's Hankel kernel ``w_k k J₀(k r)/2π`` (:meth:`brdfscale.Radial.kernel`)
    for radii on the grid ``(j − 3) h_r`` (or given radii): cached."""
    r = np.asarray(radii) if radii is not None else (np.arange(n_r) - 3) * h_r
    k, kernel = Radial.kernel(K, n_k, r)
    kernel.setflags(write=False)
    return k, kernel


def _plan_radial(material, path, u, log_mu, tol):
    budget = tol / 4
    radius = np.linalg.norm(u, axis=-1)
    r_max = float(radius.max())
    distinct = np.unique(log_mu)
    probe = distinct if len(distinct) <= 64 else np.linspace(distinct[0], distinct[-1], 64)
    # K from the tail bound |g(r) − g_K(r)| ≤ (2π)⁻¹ ∫_K^∞ |G| k dk ≤ budget · g(0), on
    # log-spaced probe frequencies scaled to the lobe's core (its extent at 10⁻³ of the peak:
    # a heavy tail's reach at the budget would pull the window below the lobe's bandwidth),
    # all probe scales in one call
    core = max(budget, CORE_TOL)
    density = evolved_density(material, np.exp(probe[0]), path.sized(64, None), budget)
    extent = float(density.support_radius(core))
    spread = float(density.support_radius(budget))  # G oscillates over the lobe's extent
    k_probe = np.logspace(-3, 5, 801) / max(extent, 1e-12)
    G = _radial_transform_rows(material, probe, k_probe, budget)
    # the library's cut-off (tail criterion, brdfscale.select's), scale by scale; the largest
    per_scale = jax.vmap(lambda g: cutoff(jnp.asarray(k_probe), g[:, None], budget))(jnp.abs(jnp.asarray(G)))
    K = float(jnp.max(per_scale))
    if not K < k_probe[-1]:
        raise InvalidInputError(
            f"tol={tol:g}: the evolved lobe's transform does not decay enough within eight decades of "
            "frequency above the lobe's width to meet it (or tol is below the rounding of its evaluation); "
            "choose a larger tol."
        )
    n_k = radial_nodes(K, r_max + spread, budget)
    k, wk = Radial.frequencies(K, n_k)
    G = _radial_transform_rows(material, probe, k, budget)
    peak = np.abs(G) @ (wk * k) / (2 * np.pi)
    fourth = np.abs(G) @ (wk * k**5) / (2 * np.pi)
    h_r = float(np.min((budget * peak / (_CUBIC_CONSTANT * fourth)) ** 0.25))
    n_r = math.ceil(r_max / h_r) + 7
    _, kernel = _hankel_kernel(K, n_k, None, h_r, n_r)
    kernel_j = jnp.asarray(kernel)
    nodes, exact, mu_error = scale_nodes(
        log_mu, lambda t: _radial_transform_rows(material, t, k, budget) @ kernel, budget
    )
    n_s, n_q = len(nodes), len(radius)
    evaluations = 3 * n_s * n_k
    table_cost = _cost.units(evaluations, n_s * n_k * n_r + 32 * n_q)
    direct_cost = _cost.units(evaluations, n_q * n_k)
    direct = exact and n_q * n_k <= _DIRECT_MEMORY and direct_cost < table_cost
    if direct:
        _, kernel = _hankel_kernel(K, n_k, tuple(radius), 0.0, 0)
        kernel_j, r_error = jnp.asarray(kernel), 0.0
    else:
        r_error = budget
    step = RadialStep(
        jnp.asarray(u), jnp.asarray(log_mu), jnp.asarray(nodes), jnp.asarray(k), kernel_j, h_r, exact, direct, budget
    )
    scales = (
        f"{n_s} distinct scales" if exact else f"{n_s} log-μ nodes ({np.exp(nodes[0]):.3g}–{np.exp(nodes[-1]):.3g})"
    )
    layout = f"at the {n_q} query radii" if direct else f"on {n_r} radii (h = {h_r:.3g}), cubic in (log μ, r)"
    details = f"K = {K:.4g}, {n_k} Gauss–Legendre nodes; {scales}; lobe {layout}"
    return (
        step,
        path.path,
        "lobe and statistics are radially symmetric; no closed form",
        budget + r_error + mu_error,
        min(table_cost, direct_cost) if direct else table_cost,
        details,
    )


# -- grid -----------------------------------------------------------------------------------
def _plan_grid(material, path, u, log_mu, tol):
    budget = tol / 4
    distinct = np.unique(log_mu)
    probe = distinct if len(distinct) <= 16 else np.linspace(distinct[0], distinct[-1], 16)
    size, achieved = 0, budget
    for t in probe:
        n, honoured = grid_size(
            evolved_density(material, np.exp(t), path.sized(256, None), budget), _MAX_GRID, truncation=budget
        )
        size, achieved = max(size, n), max(achieved, honoured)
    n_q, half = len(u), size // 2 + 1
    direct_cost = _cost.units(3 * len(distinct) * size * half, 4 * n_q * len(distinct) * size * half)
    # a table needs cubic interpolation between its nodes: typically 4× the Nyquist grid
    big = _TABLE_OVERSAMPLING * size
    table_cost_guess = _cost.units(
        3 * len(distinct) * big * (big // 2 + 1), len(distinct) * _cost.fft2_multiply_adds(big) + 128 * n_q
    )
    if len(distinct) <= 16 and n_q * size * 2 <= _DIRECT_MEMORY and direct_cost <= table_cost_guess:
        return _plan_grid_direct(material, path, u, log_mu, size, achieved, direct_cost)

    def tables(n, t):
        def chunk_tables(chunk):
            return _grid_tables(
                GridStep(jnp.zeros((1, 2)), jnp.zeros(1), chunk, None, None, n, True, achieved), material
            )

        return in_chunks(chunk_tables, t, max(1, min(_CHUNK, _GRID_CHUNK_NODES // (n * n))))

    ends = np.array([distinct[0], distinct[-1]]) if len(distinct) > 1 else distinct
    while True:
        coarse, fine = tables(size, ends), tables(2 * size, ends)
        odd = np.arange(1, 2 * size - 1, 2) / 2
        Y, X = np.meshgrid(odd, odd, indexing="ij")
        pos = np.stack([Y.ravel(), X.ravel()], -1)
        errors = []
        for c, f in zip(coarse, fine):
            guess = interpolate(c, pos, xp=np)
            errors.append(np.max(np.abs(guess - f[1::2, 1::2][: len(odd), : len(odd)].ravel())) / np.max(f))
        u_error = float(max(errors))
        if u_error <= budget or 2 * size > _MAX_GRID:
            break
        size *= 2
    nodes, exact, mu_error = scale_nodes(log_mu, lambda t: tables(size, t), budget)
    n_s = len(nodes)
    cost = _cost.units(3 * n_s * size * (size // 2 + 1), n_s * _cost.fft2_multiply_adds(size) + 128 * n_q)
    step = GridStep(jnp.asarray(u), jnp.asarray(log_mu), jnp.asarray(nodes), None, None, size, exact, achieved)
    scales = (
        f"{n_s} distinct scales" if exact else f"{n_s} log-μ nodes ({np.exp(nodes[0]):.3g}–{np.exp(nodes[-1]):.3g})"
    )
    relaxed = "" if achieved <= budget else f" (grid capped at {_MAX_GRID}: truncation {achieved:.1g})"
    details = f"{size}×{size} FFT grid per scale node{relaxed}; {scales}; cubic in (log μ, u_y, u_x)"
    return (
        step,
        path.path,
        "lobe or statistics not radially symmetric; no closed form",
        achieved + u_error + mu_error,
        cost,
        details,
    )


def _plan_grid_direct(material, path, u, log_mu, size, achieved, cost):
    """Few queries: the inverse DFT summed at the queries, phases frozen (no interpolation)."""
    nodes = np.unique(log_mu)
    h, _ = evolved_density(material, np.exp(nodes[0]), path.sized(size, None), achieved).grid_spacing()
    h = float(h)
    fy = np.fft.fftfreq(size) * (2 * np.pi / h)
    fx = np.fft.rfftfreq(size) * (2 * np.pi / h)
    W = np.stack(np.broadcast_arrays(fx[None, :], fy[:, None]), -1)
    phases = (
        jnp.asarray(np.exp(1j * u[:, 1, None] * fy[None, :])),
        jnp.asarray(np.exp(1j * u[:, 0, None] * fx[None, :])),
    )
    step = GridStep(
        jnp.asarray(u), jnp.asarray(log_mu), jnp.asarray(nodes), phases, jnp.asarray(W), size, True, achieved
    )
    details = (
        f"{size}×{size} frequency grid per scale; {len(nodes)} distinct scales; inverse DFT summed at the "
        f"{len(u)} query offsets (no interpolation)"
    )
    return (
        step,
        path.path,
        "lobe or statistics not radially symmetric; no closed form; few queries",
        achieved,
        cost,
        details,
    )


def _radial_transform_rows(material, nodes, k, tol):
    """Concrete ``G(k, μ)`` (len(nodes), len(k)) of the radial path, evaluated in fixed-size
    blocks of scales × frequencies (one compilation for every probe of the planner)."""

    def block(node_chunk, k_chunk):
        step = RadialStep(
            jnp.zeros((1, 2)),
            jnp.zeros(1),
            node_chunk,
            k_chunk,
            jnp.zeros((k_chunk.shape[0], 1)),
            1.0,
            True,
            False,
            tol,
        )
        return _radial_transforms(step, material)

    def rows(node_chunk):  # (chunk nodes, len(k)): frequencies in chunks along the second axis
        return in_chunks(lambda k_chunk: block(node_chunk, k_chunk).T, k, _CHUNK).T

    return in_chunks(rows, nodes, _CHUNK)


_PLANNERS = {"closed_form": _plan_closed_form, "radial": _plan_radial, "grid": _plan_grid}
"""The planning procedure of each evolution path, by the chosen method's own ``path`` name."""
_radial_transforms = eqx.filter_jit(lambda step, material: step.transforms(material))
_geometry = jax.jit(lambda i, o, m_inf: (half_slope(i, o) - m_inf, microfacet_factor(i, o)))
_grid_tables = eqx.filter_jit(lambda step, material: step.table(material))
