"""Evaluation of many queries in blocks whose temporaries fit a memory budget.

Every evaluation over queries (offsets, radii, directions) in the library is a function of one
query at a time, vectorised over a block. :func:`in_blocks` runs it over blocks of rows sized so
that a block's temporaries stay within ``budget`` bytes, in one compiled loop
(``lax.scan`` over the full blocks plus one call on the remainder): the program's temporaries
are then bounded by the budget whatever the number of queries, apart from the input and the
output themselves (tests/test_evaluation_contract.py checks the compiled program's buffers).
"""

import jax
import jax.numpy as jnp


DEFAULT_BUDGET = 256 * 2**20
"""Bytes of temporaries an evaluation may hold at once (256 MiB)."""


def block_rows(bytes_per_row: float, budget: int = DEFAULT_BUDGET) -> int:
    """Rows per block for temporaries of ``bytes_per_row`` each within ``budget``."""
    return max(1, int(budget // max(bytes_per_row, 1.0)))


def in_blocks(fn, rows, bytes_per_row: float, budget: int = DEFAULT_BUDGET):
    """``fn(rows)`` computed block by block along the leading axis.

    ``fn`` maps an array (or pytree of arrays) with leading axis B to an array (or pytree)
    with leading axis B, row by row (rows must not interact). ``bytes_per_row``: the
    temporaries ``fn`` holds per row.
    """
    leaves = jax.tree_util.tree_leaves(rows)
    n = leaves[0].shape[0]
    size = block_rows(bytes_per_row, budget)
    if n <= size:
        return fn(rows)
    full, rest = divmod(n, size)
    head = jax.tree_util.tree_map(lambda x: x[: full * size].reshape(full, size, *x.shape[1:]), rows)
    _, out = jax.lax.scan(lambda carry, block: (carry, fn(block)), None, head)
    out = jax.tree_util.tree_map(lambda y: y.reshape(full * size, *y.shape[2:]), out)
    if rest == 0:
        return out
    tail = fn(jax.tree_util.tree_map(lambda x: x[full * size :], rows))
    return jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), out, tail)


def itemsize(dtype) -> int:
    return jnp.dtype(dtype).itemsize
