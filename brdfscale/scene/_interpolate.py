"""Cubic Lagrange interpolation on uniform grids (tensor products in 1–3 dimensions).

Four-point Lagrange interpolation between the middle nodes of its stencil has error
``≤ (9/16)/4! · h⁴ max|f⁗|``; the stencil is clamped at the ends of the grid, so queries never read
outside it. Positions are given in index units ``x = (t − t_0)/h``.
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


def interpolate(table, positions, xp=jnp):
    """Interpolate ``table`` (d leading grid axes, then any trailing axes) at index positions
    ``positions`` (Q, d) → (Q, ...trailing). An axis shorter than 4 is not interpolated:
    its positions must be node indices (the nearest node is read). ``xp``: the array
    namespace, ``numpy`` for concrete planning-time tables (no compilation per shape)."""
    d = positions.shape[-1]
    index, weight = [], []
    for axis in range(d):
        n = table.shape[axis]
        if n < 4:
            index.append(xp.round(positions[..., axis]).astype(int)[..., None])
            weight.append(xp.ones(positions.shape[:-1] + (1,), table.dtype))
        else:
            base, w = cubic_stencil(positions[..., axis], n, xp)
            index.append(base[..., None] + xp.arange(4))
            weight.append(w)
    # gather the (≤ 4^d) stencil values, then contract the stencil axes one by one
    stencil = xp.meshgrid(*[xp.arange(ix.shape[-1]) for ix in index], indexing="ij")
    values = table[tuple(ix[:, s] for ix, s in zip(index, stencil))]  # (Q, s_1, …, s_d, trailing)
    for w in weight:
        values = xp.einsum("qs...,qs->q...", values, w)
    return values
