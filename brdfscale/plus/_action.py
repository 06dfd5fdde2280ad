"""The action of the plus-distributions on test functions, by radial quadrature (docs/conventions.md §4).

For a test function whose angular mean about the distribution's centre is ``ψ̄(x)``,

    ⟨h_n, ψ⟩ = ∫_0^{x0} (logⁿ(x/x0)/x) (ψ̄(x) − ψ̄(0)) dx = ∫_0^∞ (−v)ⁿ E(x0 e^{−v}) dv,

with ``x = x0 e^{−v}`` and the excess ``E(x) = ψ̄(x) − ψ̄(0)``. For ψ smooth on the length
``scale``, E is even in x: ``E(x) = a₂ (x/x1)² + a₄ (x/x1)⁴ + O((x/scale)⁶)`` below
``x1 = 1e-2 · scale``, with ``a₂, a₄`` from ``E(x1)`` and ``E(x1/2)``. The part
``v > v1 = ln(x0/x1)`` is integrated exactly on that polynomial,

    ∫_{v1}^∞ (−v)ⁿ e^{−p(v − v1)} dv = (−1)ⁿ Σ_k n!/(n−k)! v1^{n−k} / p^{k+1},   p = 2, 4,

(relative error ~(x1/scale)⁶ = 1e-12 of the tail) instead of summing the rounding noise of ``ψ̄(x) − ψ̄(0)`` with the
growing weights ``vⁿ``. ``[0, v1]`` is split into equal panels, refined at caller-supplied break
points (radii where E changes quickly), each integrated by 16-node Gauss–Legendre. What remains
is the rounding of E itself: an absolute error of about ``ε |ψ| v1^{n+1}/(n+1)``.
"""

import math

import jax.numpy as jnp
import numpy as np


_PANELS = 48
_NODES = 16
_POLYNOMIAL_BELOW = 1e-2
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_NODES)


def _tail_weights(v1, p: int, max_order: int):
    """∫_{v1}^∞ (−v)ⁿ e^{−p(v − v1)} dv for n = 0..max_order; shape (..., max_order+1)."""
    out = []
    for n in range(max_order + 1):
        total = sum(math.factorial(n) / math.factorial(n - k) * v1 ** (n - k) / p ** (k + 1) for k in range(n + 1))
        out.append((-1) ** n * total)
    return jnp.stack(out, axis=-1)


def radial_action(excess, x0, max_order: int, scale, breaks=None):
    """``∫_0^{x0} (logⁿ(x/x0)/x) excess(x) dx`` for n = 0..max_order; shape (..., max_order+1).

    ``excess(x)`` maps radii of shape (..., k) to ``ψ̄(x) − ψ̄(0)`` of the same shape (the
    leading dimensions are those of ``scale`` and ``breaks`` broadcast together). ``breaks``
    (..., b) are radii where ``excess`` changes quickly; ``scale`` (...) is the length on which
    it varies near the centre.
    """
    x0 = jnp.asarray(x0)
    scale = jnp.asarray(scale)
    dtype = jnp.result_type(x0, scale, float)
    v1 = jnp.maximum(jnp.log(x0 / (_POLYNOMIAL_BELOW * scale)), 0.0)  # (...)
    edges = v1[..., None] * jnp.linspace(0.0, 1.0, _PANELS + 1, dtype=dtype)
    if breaks is not None:
        breaks = jnp.asarray(breaks, dtype)
        v_breaks = jnp.clip(jnp.log(x0 / jnp.maximum(breaks, jnp.finfo(dtype).tiny)), 0.0, v1[..., None])
        lead = jnp.broadcast_shapes(edges.shape[:-1], v_breaks.shape[:-1])
        edges = jnp.sort(
            jnp.concatenate(
                [
                    jnp.broadcast_to(edges, lead + edges.shape[-1:]),
                    jnp.broadcast_to(v_breaks, lead + v_breaks.shape[-1:]),
                ],
                axis=-1,
            ),
            axis=-1,
        )
    lo, hi = edges[..., :-1, None], edges[..., 1:, None]
    half = (hi - lo) / 2
    v = (lo + half * (1 + jnp.asarray(_GL_X, dtype))).reshape(edges.shape[:-1] + (-1,))
    w = (half * jnp.asarray(_GL_W, dtype)).reshape(v.shape)
    # the nodes and, last, x1 = x0 e^{−v1} and x1/2 for the tail: one call of excess
    ends = jnp.broadcast_to(v1[..., None], v.shape[:-1] + (1,)) + jnp.asarray([0.0, math.log(2.0)], dtype)
    e = excess(x0 * jnp.exp(-jnp.concatenate([v, ends], axis=-1)))
    values, e1, e_half = w * e[..., :-2], e[..., -2], e[..., -1]
    a4 = (4.0 / 3.0) * (e1 - 4 * e_half)
    a2 = e1 - a4
    out = []
    power = jnp.ones_like(v)
    for _ in range(max_order + 1):
        out.append(jnp.sum(power * values, axis=-1))
        power = power * (-v)
    v1 = jnp.broadcast_to(v1, e1.shape)
    tail = a2[..., None] * _tail_weights(v1, 2, max_order) + a4[..., None] * _tail_weights(v1, 4, max_order)
    return jnp.stack(out, axis=-1) + tail
