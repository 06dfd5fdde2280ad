"""The action of the plus-distributions on test functions, by radial quadrature (DESIGN §4).

For a test function whose angular mean about the distribution's centre is ``ψ̄(x)``,

    ⟨h_n, ψ⟩ = ∫_0^{x0} (logⁿ(x/x0)/x) (ψ̄(x) − ψ̄(0)) dx = ∫_0^∞ (−v)ⁿ (ψ̄(x0 e^{−v}) − ψ̄(0)) dv,

with ``x = x0 e^{−v}``. For a test function smooth on the length ``scale``,
``ψ̄(x) − ψ̄(0) = O((x/scale)²)``, so the v-integrand decays like ``e^{−2v}`` once
``x0 e^{−v} < scale`` and the integral is cut at ``v_max = max(ln(x0/scale), 0) + 20``
(neglected part below ``e^{−40}`` relative). ``[0, v_max]`` is split into equal panels, refined
at caller-supplied break points (where ψ̄ changes quickly), each integrated by 16-node
Gauss–Legendre.
"""

import jax.numpy as jnp
import numpy as np

_PANELS = 48
_NODES = 16
_TAIL = 20.0
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_NODES)


def radial_action(excess, x0, max_order: int, scale, breaks=None):
    """``∫_0^{x0} (logⁿ(x/x0)/x) excess(x) dx`` for n = 0..max_order; shape (..., max_order+1).

    ``excess(x)`` maps radii of shape (..., nodes) to ``ψ̄(x) − ψ̄(0)`` of the same shape (the
    leading dimensions are those of ``scale`` and ``breaks`` broadcast together). ``breaks``
    (..., b) are radii where ``excess`` changes quickly; ``scale`` (...) is the length on which
    it varies near the centre.
    """
    x0 = jnp.asarray(x0)
    scale = jnp.asarray(scale)
    dtype = jnp.result_type(x0, scale, float)
    v_max = jnp.maximum(jnp.log(x0 / scale), 0.0) + _TAIL  # (...)
    edges = v_max[..., None] * jnp.linspace(0.0, 1.0, _PANELS + 1, dtype=dtype)
    if breaks is not None:
        breaks = jnp.asarray(breaks, dtype)
        v_breaks = jnp.log(x0 / jnp.maximum(breaks, 1e-300))
        v_breaks = jnp.clip(v_breaks, 0.0, v_max[..., None])
        lead = jnp.broadcast_shapes(edges.shape[:-1], v_breaks.shape[:-1])
        edges = jnp.sort(jnp.concatenate([jnp.broadcast_to(edges, lead + edges.shape[-1:]),
                                          jnp.broadcast_to(v_breaks, lead + v_breaks.shape[-1:])], axis=-1),
                         axis=-1)
    lo, hi = edges[..., :-1, None], edges[..., 1:, None]
    half = (hi - lo) / 2
    v = (lo + half * (1 + jnp.asarray(_GL_X, dtype))).reshape(edges.shape[:-1] + (-1,))
    w = (half * jnp.asarray(_GL_W, dtype)).reshape(v.shape)
    values = w * excess(x0 * jnp.exp(-v))
    out = []
    power = jnp.ones_like(v)
    for _ in range(max_order + 1):
        out.append(jnp.sum(power * values, axis=-1))
        power = power * (-v)
    return jnp.stack(out, axis=-1)
