"""Planning the SO(3) path for an :class:`AnisotropicMaterial` (seed §5, docs/conventions.md §3).

On the distinct (i, o) pairs, global orientations Γ∞ and scales μ its queries present:

1. **Band limit from the error target, a priori.** The evolved BRDF's degree-J content is
   at most the lobe's, ``a_J`` (:meth:`brdfscale.so3.AnisotropicMicrofacetLobe.spectrum`: its
   narrowest width), damped by the propagator ``exp(−Δτ G^J)`` whose eigenvalues are
   ``≥ min(D) J(J+1)`` (``G = Σ D_k J_k² ⪰ min(D) J²``), Δτ = τ(μ0) − τ(μ) ≥ its smallest
   value over the queried scales. :func:`brdfscale.so3.band_limit` on
   ``a_J e^{−Δτ_min min(D) J(J+1)}`` with a quarter of the target gives B (degrees J < B).
2. **Sampling band limit (no aliasing).** The lobe at μ0 is narrower than the evolved BRDF.
   The Kostelec–Rockmore quadrature of band limit B_s gives degree J exactly when the
   sampled function has no content at degrees ≥ 2B_s − J; with B0 the lobe's own band limit
   (``band_limit(a_J, tol/4)``), ``B_s = max(B, ⌈(B + B0)/2⌉)`` keeps the aliasing of every
   kept degree J < B below the same quarter of the target.
3. **Only the orders needed.** Twist columns M': a lobe whose facet-frame slope density is
   radially symmetric depends on the facet normal only (M' = 0); the propagator is diagonal
   in M' when ``D_x = D_y`` (then columns do not mix), otherwise all |M'| < B are kept. Rows
   M: on a flat global orientation (all queries at β∞ = 0) ``D^J_{MM'}`` is diagonal, so
   the rows |M| ≤ (largest column) suffice; otherwise all |M| < B.
4. **Scales**: as on the other paths (:mod:`._scales`) — exact when few, else log-μ nodes
   with cubic interpolation checked at the midpoints.

Only scales at or above μ0 (τ(μ) ≤ τ(μ0), a stable blur) are planned.
"""

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import so3
from .._errors import InvalidInputError, NoBRDFAtScaleError
from . import _cost
from ._description import AnisotropicMaterial
from ._scales import in_chunks, scale_nodes
from ._steps import SO3Step


_MAX_COEFFICIENTS = 5e7  # (i, o) pairs × scale nodes × kept coefficients held at once


def plan_so3(material: AnisotropicMaterial, i, o, angles, log_mu, tol):
    """Plan the SO(3) path for one material's queries: ``(inverse, planned)``.

    ``i``, ``o`` (q, 3), ``angles`` (q, 3) Euler angles of Γ∞, ``log_mu`` (q,). ``inverse`` maps
    each query to its distinct (pair, Γ∞, μ) key; ``planned`` is (step, path, reason,
    predicted error, predicted cost, details) as for the slope-space paths.
    """
    budget = tol / 4
    pair_keys, pair_of_query = np.unique(np.column_stack([i, o]), axis=0, return_inverse=True)
    pair_of_query = pair_of_query.ravel()
    keys, inverse = np.unique(np.column_stack([pair_of_query, angles, log_mu]), axis=0, return_inverse=True)
    key_pair = keys[:, 0].astype(int)
    key_angles, key_log_mu = keys[:, 1:4], keys[:, 4]

    tau0 = float(material.tau(material.mu0))
    distinct = np.unique(key_log_mu)
    tau = np.asarray(material.tau(np.exp(distinct)))
    if np.any(tau > tau0 * (1 + 1e-12)):
        finest = float(np.exp(distinct[np.argmax(tau)]))
        raise NoBRDFAtScaleError(
            f"the SO(3) path plans scales at or above μ0 = {float(material.mu0):.4g} only (a stable blur); "
            f"μ = {finest:.4g} is finer (τ = {tau.max():.4g} > τ(μ0) = {tau0:.4g}). Evolving towards finer scales "
            "is a deconvolution: use brdfscale.so3.evolve with regularisation > 0."
        )
    D = np.asarray(material.law.D)

    def lobe_spectrum(J):
        return np.asarray(material.lobe.spectrum(J))

    damping = (tau0 - tau.max()) * D.min()
    B, truncation = so3.band_limit(lambda J: lobe_spectrum(J) * np.exp(-damping * J * (J + 1)), budget)
    B0, _ = so3.band_limit(lobe_spectrum, budget)
    B_s = max(B, math.ceil((B + B0) / 2))
    aliasing = so3.truncation_error(lobe_spectrum, 2 * B_s - B + 1)

    twist_free = _twist_free(material.lobe)
    diagonal = bool(D[0] == D[1])
    lobe_columns = 0 if twist_free else B - 1
    columns = lobe_columns if diagonal else B - 1
    flat = bool(np.all(key_angles[:, 1] == 0))
    rows = columns if flat else B - 1

    # each pair's distinct orientations, padded to a common count
    slot = np.empty(len(keys), int)
    per_pair = []
    for p in range(len(pair_keys)):
        mine = np.flatnonzero(key_pair == p)
        distinct_angles, slot[mine] = np.unique(key_angles[mine], axis=0, return_inverse=True)
        per_pair.append(distinct_angles)
    q_max = max(len(a) for a in per_pair)
    padded = np.stack([np.concatenate([a, np.repeat(a[-1:], q_max - len(a), axis=0)]) for a in per_pair])
    n_pairs = len(pair_keys)

    def step_at(nodes, exact):
        return SO3Step(
            jnp.asarray(pair_keys.reshape(-1, 2, 3)),
            jnp.asarray(padded),
            jnp.asarray(key_pair),
            jnp.asarray(slot),
            jnp.asarray(key_log_mu),
            jnp.asarray(nodes),
            B,
            B_s,
            rows,
            lobe_columns,
            columns,
            diagonal,
            exact,
        )

    kept = B * (2 * rows + 1) * (2 * columns + 1)
    if n_pairs * min(len(distinct), 64) * kept > _MAX_COEFFICIENTS:
        raise InvalidInputError(
            f"the SO(3) path would hold {n_pairs} (i, o) pairs × {len(distinct)} scales × {kept} coefficients "
            f"(B = {B}); that is too many. Query fewer distinct direction pairs or relax tol."
        )
    lobe = []  # the lobe's coefficients, computed once when tables are needed (they differ only in their nodes)

    def tables(t):
        if not lobe:
            lobe.append(_lobe_coefficients(step_at(distinct[:1], True), material))
        return in_chunks(lambda nodes: np.asarray(_node_values(step_at(nodes, True), material, lobe[0])).T, t, 64)

    nodes, exact, mu_error = scale_nodes(key_log_mu, tables, budget)
    step = step_at(nodes, exact)
    cost = _predicted_cost(n_pairs, len(nodes), q_max, B, B_s, rows, lobe_columns, columns, diagonal)

    n_s = len(nodes)
    scales = (
        f"{n_s} distinct scales" if exact else f"{n_s} log-μ nodes ({np.exp(nodes[0]):.3g}–{np.exp(nodes[-1]):.3g})"
    )
    row_reason = (
        "all queries at a flat global orientation: D^J diagonal, rows |M| ≤ columns"
        if flat
        else "tilted global orientations need every row"
    )
    column_reason = "the lobe depends on the facet normal only" if twist_free else "the lobe depends on the twist"
    column_reason += (
        ", D_x = D_y: the propagator does not mix twist orders"
        if diagonal
        else ", D_x ≠ D_y: the propagator mixes twist orders, all kept"
    )
    details = (
        f"band limit B = {B} (degrees J < B; a-priori truncation ε(B) = {truncation:.1g} from the lobe's width and the "
        f"least damping Δτ = {tau0 - tau.max():.3g}); lobe sampled at band limit {B_s} (its own band limit {B0}: "
        f"aliasing ≤ {aliasing:.1g}); rows |M| ≤ {rows} ({row_reason}); twist columns |M'| ≤ {columns} "
        f"({column_reason}); {n_pairs} (i, o) pairs, {len(keys)} distinct (pair, Γ∞, μ); {scales}"
    )
    reason = "the BRDF depends on the facet's orientation on SO(3) (tilt and twist)"
    return inverse.ravel(), (step, "so3", reason, truncation + aliasing + mu_error, cost, details)


def _twist_free(lobe: so3.AnisotropicMicrofacetLobe) -> bool:
    """Whether the lobe's facet-frame slope density is radially symmetric (then ρ(i, o, Γ)
    depends on the facet normal Γẑ only): its density compared on circles of slopes
    |m| = 1e-3 … 1 (an anisotropic density differs on every circle where it does not underflow)."""
    radius = np.geomspace(1e-3, 1.0, 7)[:, None]
    phi = np.linspace(0, 2 * np.pi, 17)[None, :-1]
    m = np.stack(np.broadcast_arrays(radius * np.cos(phi), radius * np.sin(phi)), -1)
    g = np.asarray(lobe.shape.density(jnp.asarray(m)))
    return bool(np.all(np.abs(g - g[:, :1]) <= 1e-12 * np.abs(g[:, :1])))


def _predicted_cost(pairs, scales, per_pair, B, B_s, rows, lobe_columns, columns, diagonal) -> float:
    """Cost units (:mod:`._cost`): lobe samples and forward transforms per pair, the
    propagators, synthesis (one O(B²·orders) contraction per pair and scale, then
    O(B·orders) per orientation)."""
    n = 2 * B_s
    forward_orders = (2 * rows + 1) * (2 * lobe_columns + 1)
    orders = (2 * rows + 1) * (2 * columns + 1)
    evaluations = 6.0 * pairs * n**3 + pairs * scales * per_pair * (B + 2 * rows + 2 * columns + 2)
    work = pairs * (_cost.fft_multiply_adds(n**3) + 3.0 * n * B_s * forward_orders + B_s**2 * forward_orders)
    if diagonal:
        work += pairs * scales * B * orders
    else:
        evaluations += scales * B * 10.0 * (2 * B - 1) ** 3 / _cost.EVALUATION_UNITS
        work += pairs * scales * B * orders * (2 * lobe_columns + 1)
    work += pairs * scales * (B**2 * orders + 4.0 * per_pair * B * orders)
    return _cost.units(evaluations, work)


_lobe_coefficients = eqx.filter_jit(lambda step, material: step.lobe_coefficients(material))
_node_values = eqx.filter_jit(lambda step, material, R0: step.node_values(material, R0))
