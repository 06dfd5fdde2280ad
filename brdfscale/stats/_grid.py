"""The frequency grid of a real 2D FFT, and cheap evaluation of transforms on it."""

import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError
from .._show import Shown
from .._validation import positive


@functools.lru_cache(maxsize=32)
def _radii(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Distinct ``√(i² + j²)`` over the grid's integer nodes and, per node, which one it is."""
    i = np.fft.fftfreq(size, 1.0 / size).astype(np.int64)
    j = np.arange(size // 2 + 1, dtype=np.int64)
    unique, which = np.unique(i[:, None] ** 2 + j[None, :] ** 2, return_inverse=True)
    return np.sqrt(unique.astype(np.float64)), which.reshape(size, size // 2 + 1).astype(np.int32)


class FrequencyGrid(Shown, eqx.Module):
    """The frequencies of a real 2D FFT over an ``n × n`` slope grid of spacing ``h``.

    Nodes ``W = (Δk·j, Δk·ι(i))`` with ``Δk = 2π/(n h)``: columns ``j = 0 … n/2`` (the
    non-negative half that ``numpy.fft.rfft2`` keeps), rows ``i`` in FFT order
    (``ι(i) = i`` for ``i < n/2``, ``i − n`` otherwise). Arrays on the grid have shape
    ``(n, n//2 + 1)``: rows ``W_y``, columns ``W_x``. Units: radians per unit slope.

    Densities evaluate their transform on it with
    :meth:`~brdfscale.stats.AbstractSlopeDensity.cf_grid`, which exploits structure that a
    pointwise evaluation cannot: separable factors (diagonal Gaussians, shifts) cost one
    product per node after ``O(n)`` transcendental evaluations, and radially symmetric
    transforms are evaluated once per distinct radius (≈ n²/11 of the n²/2 nodes at n = 256).
    Parameters must be unbatched (map batches with ``jax.vmap``).
    """

    size: int = eqx.field(static=True)
    step: Float[Array, ""]

    def __init__(self, size: int, step: Float[ArrayLike, ""]):
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 2:
            raise InvalidInputError(f"size must be an integer ≥ 2 (nodes per side); got {size!r}.")
        self.size = int(size)
        self.step = positive(step, "step", "a positive frequency spacing Δk")

    @property
    def wx(self) -> Float[Array, " nx"]:
        """Column frequencies ``Δk · (0 … n/2)``."""
        return self.step * jnp.arange(self.size // 2 + 1, dtype=self.step.dtype)

    @property
    def wy(self) -> Float[Array, " n"]:
        """Row frequencies ``Δk · ι(i)`` in FFT order."""
        return self.step * jnp.asarray(np.fft.fftfreq(self.size, 1.0 / self.size), dtype=self.step.dtype)

    def nodes(self) -> Float[Array, "n nx 2"]:
        """Every node ``W`` as an ``(n, n//2 + 1, 2)`` array (for pointwise evaluation)."""
        return jnp.stack(jnp.broadcast_arrays(self.wx[None, :], self.wy[:, None]), axis=-1)

    def separable(self, along_x, along_y) -> Array:
        """``f(W_x) g(W_y)`` on the grid: ``f`` evaluated once per column, ``g`` once per row.

        ``along_x``, ``along_y``: functions of a 1D frequency array (units of ``W``).
        """
        fx = _evaluated_once(along_x, self.wx)
        fy = _evaluated_once(along_y, self.wy)
        return fy[:, None] * fx[None, :]

    def radial(self, profile) -> Array:
        """``profile(|W|)`` on the grid, evaluating ``profile`` once per distinct radius."""
        radius, which = _radii(self.size)
        return _evaluated_once(profile, self.step * jnp.asarray(radius, dtype=self.step.dtype))[which]


def axis_phase(w, offset):
    """``e^{−i w·offset}`` along one axis (1 for no offset), as a complex array."""
    if offset is None:
        return jnp.ones_like(w, dtype=jnp.result_type(w, 1j))
    return jnp.exp(-1j * w * offset)


def _evaluated_once(f, x: Float[Array, " n"]) -> Array:
    """``f(x)`` for a 1D ``x``, computed once into its own buffer.

    XLA:CPU fuses an elementwise evaluation into the per-node products and gathers that
    consume it, where it is then repeated at every grid node (several times slower on the
    grid path when profiled); ``lax.optimization_barrier`` does not stop it (the CPU compiler
    removes it), and a loop boundary (``lax.map``) stops it but runs the evaluation on one
    thread. XLA does not fuse an expensive evaluation into a reduce-window that reads each
    value twice, so the values pass through one: the running sum of ``(0, f(x))`` along a new
    axis of length 2, whose second row is ``0 + f(x) = f(x)`` exactly. The evaluation stays a
    parallel loop of its own.
    """
    values = f(x)
    # jnp.cumsum lowers to a reduce-window on CPU and, unlike lax.reduce_window with a
    # generic computation, is differentiable in both modes
    return jnp.cumsum(jnp.stack([jnp.zeros_like(values), values]), axis=0)[1]
