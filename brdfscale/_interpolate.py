"""Lagrange interpolation on uniform grids (tensor products in 1–3 dimensions).

p-point Lagrange interpolation between the middle nodes of its stencil has error
``≤ max|ω_p|/p! · hᵖ max|f⁽ᵖ⁾|`` (cubic, p = 4: ``(9/16)/4! · h⁴ max|f⁗|``); the stencil is
clamped at the ends of the grid, so queries never read outside it. Positions are given in
index units ``x = (t − t_0)/h``.
"""

import jax.numpy as jnp


def cubic_stencil(x, n: int, xp=jnp):
    """First stencil index (n ≥ 4) and the four Lagrange weights at index position ``x``
    (``xp``: the array namespace, ``numpy`` for concrete planning-time values)."""
    base = xp.clip(xp.floor(x).astype(int) - 1, 0, n - 4)
    s = x - base  # in [0, 3] inside the grid
    w0 = -(s - 1) * (s - 2) * (s - 3) / 6
    w1 = s * (s - 2) * (s - 3) / 2
    w2 = -s * (s - 1) * (s - 3) / 2
    w3 = s * (s - 1) * (s - 2) / 6
    return base, xp.stack([w0, w1, w2, w3], axis=-1)


def lagrange_stencil(x, n: int, points: int, xp=jnp):
    """First stencil index (n ≥ points, points even) and the ``points`` Lagrange weights at
    index position ``x``: the stencil is centred on the interval that holds ``x``."""
    if points == 4:
        return cubic_stencil(x, n, xp)
    half = points // 2
    base = xp.clip(xp.floor(x).astype(int) - (half - 1), 0, n - points)
    s = x - base
    weights = []
    for j in range(points):
        w = 1.0
        for i in range(points):
            if i != j:
                w = w * (s - i) / (j - i)
        weights.append(w)
    return base, xp.stack(weights, axis=-1)


def interpolate(table, positions, xp=jnp, points: int = 4):
    """Interpolate ``table`` (d leading grid axes, then any trailing axes) at index positions
    ``positions`` (Q, d) → (Q, ...trailing), with ``points``-point Lagrange stencils per axis
    (4: cubic). An axis shorter than ``points`` is not interpolated:
    its positions must be node indices (the nearest node is read). ``xp``: the array
    namespace, ``numpy`` for concrete planning-time tables (no compilation per shape)."""
    d = positions.shape[-1]
    index, weight = [], []
    for axis in range(d):
        n = table.shape[axis]
        if n < points:
            index.append(xp.round(positions[..., axis]).astype(int)[..., None])
            weight.append(xp.ones(positions.shape[:-1] + (1,), table.dtype))
        else:
            base, w = lagrange_stencil(positions[..., axis], n, points, xp)
            index.append(base[..., None] + xp.arange(points))
            weight.append(w)
    # gather the (≤ 4^d) stencil values, then contract the stencil axes one by one
    stencil = xp.meshgrid(*[xp.arange(ix.shape[-1]) for ix in index], indexing="ij")
    values = table[tuple(ix[:, s] for ix, s in zip(index, stencil))]  # (Q, s_1, …, s_d, trailing)
    for w in weight:
        values = xp.einsum("qs...,qs->q...", values, w)
    return values
