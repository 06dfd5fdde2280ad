"""Scale nodes: the distinct μ of the queries, or nodes uniform in log μ with cubic interpolation.

Shared by every path of the planner: few distinct scales are evaluated exactly; otherwise
nodes uniform in log μ (``NODES_PER_DECADE`` to start), refined by halving the spacing until
cubic interpolation in log μ — checked against exact tables at the midpoints between nodes —
is within the error budget.
"""

import math

import jax.numpy as jnp
import numpy as np

from .._interpolate import interpolate


NODES_PER_DECADE = 8
MAX_SCALE_NODES = 2049
EXACT_SCALES = 4  # at most this many distinct μ are always evaluated exactly


def midpoint_error(at_nodes, at_midpoints) -> float:
    """Largest error of cubic interpolation between ``at_nodes`` (n, ...) at the midpoints,
    against exact values ``at_midpoints`` (n − 1, ...), relative to each midpoint's peak.
    In NumPy with the evaluation's own interpolation (no compilation per table shape)."""
    n = at_nodes.shape[0]
    interpolated = interpolate(at_nodes, (np.arange(n - 1) + 0.5)[:, None], xp=np)
    peak = np.max(np.abs(at_midpoints.reshape(n - 1, -1)), axis=1)
    return float(np.max(np.max(np.abs(interpolated - at_midpoints).reshape(n - 1, -1), axis=1) / peak))


def scale_nodes(log_mu, tables, budget):
    """Scale nodes (log μ), whether they are the exact distinct scales, and the measured
    interpolation error. ``tables(nodes)`` returns concrete arrays (n, ...) of the lobe."""
    distinct = np.unique(log_mu)
    lo, hi = distinct[0], distinct[-1]
    n = max(4, math.ceil(NODES_PER_DECADE * (hi - lo) / math.log(10)) + 1)
    while len(distinct) > EXACT_SCALES and n < len(distinct) and n <= MAX_SCALE_NODES:
        nodes = np.linspace(lo, hi, n)
        mid = 0.5 * (nodes[1:] + nodes[:-1])
        values = np.asarray(tables(np.concatenate([nodes, mid])))
        error = midpoint_error(values[:n], values[n:])
        if error <= budget:
            return nodes, False, error
        n = 2 * n - 1
    return distinct, True, 0.0


def in_chunks(fn, nodes, max_chunk: int) -> np.ndarray:
    """``fn`` over the (non-empty) ``nodes`` in calls of equal size — the smallest power of two
    that holds them all, at most ``max_chunk`` — the last chunk padded by repeating the final
    node; concatenated along the node axis (first) and cut to ``len(nodes)``. Calls share their
    shapes, so planning compiles ``fn`` once for all the refinements beyond ``max_chunk``
    nodes, and small node sets are not padded far. ``fn`` returns concrete arrays, node axis
    first."""
    nodes = np.asarray(nodes)
    chunk = min(max_chunk, 1 << max(0, math.ceil(math.log2(len(nodes)))))
    padded = np.concatenate([nodes, np.full(-len(nodes) % chunk, nodes[-1])])
    return np.concatenate([np.asarray(fn(jnp.asarray(part))) for part in padded.reshape(-1, chunk)])[: len(nodes)]
