"""The degree–frequency contraction of the SO(3) transforms, blocked for the cache.

With the eigenvector rows ``X^J_{mM}`` of :mod:`._wigner` (m = 0 … J) the transforms need

    T_{MM'}(m)  = Σ_{J ≥ m} X^J_{mM} X^J_{mM'} f^J_{MM'}        (synthesis, :func:`degree_to_frequency`)
    f^J_{MM'}   = Σ_{m ≤ J} X^J_{mM} X^J_{mM'} φ_{MM'}(m)        (analysis, :func:`frequency_to_degree`).

Symmetry. ``J_y``'s tridiagonal form commutes with the flip M → −M, so
``X^J_{m,−M} = (−1)^{J+m} X^J_{mM}`` (tested). The four sign quadrants (±|M|, ±|M'|) therefore
share the kernel ``Y^J_{mμ} Y^J_{mμ'}`` over μ = |M|, μ' = |M'|; the mixed quadrants carry
``(−1)^J`` on the degree side and ``(−1)^m`` on the frequency side. Data are held in the
*quadrant layout*: real arrays ``(X, L+1, N_p, ch)`` — X the degree or frequency axis, then μ, μ'
(padded with zeros to N_p, a multiple of the tile), and the channels ``ch = (quadrant, re/im,
batch)`` last, so that every kernel entry is used by ``8 × batch`` multiply-adds.

Blocking. Degrees are cut into slabs [a, b); in a slab only m < b and μ, μ' < b occur. For
each slab one ``lax.scan`` runs over the items (μ, tile of t columns μ'); an item builds the
kernel tile ``K[μ', m, J] = Y^J_{mμ'} Y^J_{mμ}`` (t × b × (b − a) entries, sized to stay in the
L2 cache) and contracts it with all channels by a batched matrix product. Work: about
``Σ_J (J+1)³ ≈ B⁴/4`` kernel entries (plus the slab padding), memory O(B³); no array of
size O(B⁴) and no pass over the whole output per degree.
"""

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._wigner import fourier_rows


__all__ = ["Plan", "plan", "kernel_tables", "degree_to_frequency", "frequency_to_degree", "QUADRANTS", "MIXED"]

QUADRANTS = ((1, 1), (-1, -1), (1, -1), (-1, 1))
"""Signs of (M, M') in each quadrant, in channel order."""

MIXED = np.array([s != t for s, t in QUADRANTS])
"""Whether a quadrant has M and M' of opposite signs (it carries the (−1)^{J+m} factor)."""

_MAX_SLABS = 8
_TILE_ENTRIES = 32768  # kernel-tile entries (256 KiB in float64)


class Plan(NamedTuple):
    """The static blocking of a contraction: degree slab edges, column tile, padded columns."""

    B: int
    L: int
    N: int
    edges: tuple[int, ...]
    tile: int
    columns: int  # N_p: N + 1 rounded up to a multiple of the tile


def _round_up(n: int, t: int) -> int:
    return -(-n // t) * t


@functools.lru_cache(maxsize=64)
def plan(B: int, L: int, N: int) -> Plan:
    """The blocking for band limit B and orders |M| ≤ L, |M'| ≤ N."""
    slabs = max(1, min(_MAX_SLABS, B // 4))
    edges = tuple(sorted({round(B * k / slabs) for k in range(slabs + 1)}))
    width = max(b - a for a, b in zip(edges[:-1], edges[1:]))
    tile = max(1, min(N + 1, _TILE_ENTRIES // (B * width)))
    return Plan(B, L, N, edges, tile, _round_up(N + 1, tile))


def _slabs(p: Plan):
    return list(zip(p.edges[:-1], p.edges[1:]))


@functools.lru_cache(maxsize=6)
def _tables_f64(p: Plan) -> tuple[np.ndarray, ...]:
    out = []
    for a, b in _slabs(p):
        rows = max(min(b, p.L + 1), _round_up(min(b, p.N + 1), p.tile))
        Z = np.zeros((rows, b, b - a))
        for J in range(a, b):
            X = fourier_rows(J)  # (m ≤ J, M = −J … J)
            k = min(J + 1, rows)
            Z[:k, : J + 1, J - a] = X[:, J : J + k].T  # Z[μ, m, J − a] = X^J_{m, μ}
        Z.setflags(write=False)
        out.append(Z)
    return tuple(out)


def kernel_tables(p: Plan, dtype) -> tuple[jax.Array, ...]:
    """Per slab [a, b): ``Z[μ, m, J − a] = X^J_{mμ}`` for μ ≥ 0 (zero where m > J or μ > J)."""
    return tuple(jnp.asarray(z, dtype) for z in _tables_f64(p))


def _items(p: Plan, b: int):
    """The (μ, first column) pairs a slab ending at degree b visits."""
    mu, col = np.meshgrid(np.arange(min(b, p.L + 1)), np.arange(0, min(b, p.N + 1), p.tile), indexing="ij")
    return jnp.asarray(mu.ravel()), jnp.asarray(col.ravel())


def _kernel_tile(z, mu, col, tile):
    """``K[μ', m, J] = Z[μ', m, J] Z[μ, m, J]`` for the columns col … col + tile − 1."""
    row = jax.lax.dynamic_index_in_dim(z, mu, 0, keepdims=False)
    return jax.lax.dynamic_slice_in_dim(z, col, tile, 0) * row[None]


def degree_to_frequency(p: Plan, tables, g):
    """``T[m, μ, μ', c] = Σ_J Y^J_{mμ} Y^J_{mμ'} g[J, μ, μ', c]`` in the quadrant layout
    (g of shape (B, L+1, N_p, ch); the quadrant signs are the caller's)."""
    ch = g.shape[-1]
    T = jnp.zeros(g.shape, g.dtype)
    for (a, b), z in zip(_slabs(p), tables):

        def add_item(T, item, z=z, a=a, b=b):
            mu, col = item
            K = _kernel_tile(z, mu, col, p.tile)  # (t, b, b − a)
            gt = jax.lax.dynamic_slice(g, (a, mu, col, 0), (b - a, 1, p.tile, ch))[:, 0]  # (b − a, t, ch)
            part = jax.lax.dot_general(K, gt, (((2,), (0,)), ((0,), (1,))))  # (t, b, ch)
            start = (0, mu, col, 0)
            old = jax.lax.dynamic_slice(T, start, (b, 1, p.tile, ch))
            return jax.lax.dynamic_update_slice(T, old + jnp.swapaxes(part, 0, 1)[:, None], start), None

        T, _ = jax.lax.scan(add_item, T, _items(p, b))
    return T


def frequency_to_degree(p: Plan, tables, phi):
    """``f[J, μ, μ', c] = Σ_m Y^J_{mμ} Y^J_{mμ'} φ[m, μ, μ', c]``: the transpose of
    :func:`degree_to_frequency`."""
    ch = phi.shape[-1]
    f = jnp.zeros(phi.shape, phi.dtype)
    for (a, b), z in zip(_slabs(p), tables):

        def set_item(f, item, z=z, a=a, b=b):
            mu, col = item
            K = _kernel_tile(z, mu, col, p.tile)  # (t, b, b − a)
            pt = jax.lax.dynamic_slice(phi, (0, mu, col, 0), (b, 1, p.tile, ch))[:, 0]  # (b, t, ch)
            part = jax.lax.dot_general(K, pt, (((1,), (0,)), ((0,), (1,))))  # (t, b − a, ch)
            return jax.lax.dynamic_update_slice(f, jnp.swapaxes(part, 0, 1)[:, None], (a, mu, col, 0)), None

        f, _ = jax.lax.scan(set_item, f, _items(p, b))
    return f
