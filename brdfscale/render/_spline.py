"""Cubic B-spline interpolation of tables, the way Dr.Jit's textures evaluate it (issue 33 item 1, ``form="spline"``).

A table of values ``v_j`` on the nodes ``j = 0 … n−1`` of a uniform axis is interpolated by the cubic B-spline

    f(x) = Σ_k c_k B₃(x − k),    B₃(t) = 2/3 − t² + |t|³/2 (|t| < 1),  (2 − |t|)³/6 (1 ≤ |t| < 2),  0 beyond,

whose coefficients ``c`` are *prefiltered* so that it passes through the values, ``f(j) = (c_{j−1} + 4c_j +
c_{j+1})/6 = v_j``. Dr.Jit's ``Texture.eval_cubic`` evaluates exactly this sum over a texture holding ``c``
(texel-centred: node j at texture coordinate ``(j + ½)/n``), with the coefficients beyond the ends clamped to the
end ones (``c_{−1} = c_0``, ``c_n = c_{n−1}``) — so :func:`prefilter` solves the tridiagonal system with that
boundary (rows ``(5c_0 + c_1)/6 = v_0`` and ``(c_{n−2} + 5c_{n−1})/6 = v_{n−1}``), and a periodic axis (an azimuth)
the circulant one, padded with :data:`PERIODIC_PAD` wrapped coefficients on each side so that clamping never
reaches the wrapped ones. The interpolation error of a smooth function falls as h⁴ (the bilinear one's as h²).
:func:`on_grid` evaluates the same sum on the host (NumPy): the ladder and grid refinement check it, and
tests/test_render.py checks ``eval_cubic`` against it and it against SciPy's ``BSpline``.
"""

import numpy as np
from scipy.linalg import solve_banded


PERIODIC_PAD = 3
"""Wrapped coefficients added on each side of a periodic axis (the B-spline reaches two nodes; one to spare)."""

GHOSTS = 2
"""Levels extrapolated beyond each end of a run of the ladder (:func:`runs_coefficients`)."""


def basis(t: np.ndarray) -> np.ndarray:
    """The cubic B-spline ``B₃(t)`` (module docstring)."""
    t = np.abs(np.asarray(t, float))
    return np.where(t < 1, 2 / 3 - t**2 + t**3 / 2, np.where(t < 2, (2 - t) ** 3 / 6, 0.0))


def _solve(values: np.ndarray, axis: int, extrapolated: bool) -> np.ndarray:
    v = np.moveaxis(values, axis, 0)
    n = v.shape[0]
    if n == 1:
        return np.moveaxis(v.copy(), 0, axis)
    if extrapolated and n < 4:
        raise ValueError("a cubic closure needs at least 4 nodes")  # extend() always gives it ≥ 5
    u = 3
    bands = np.zeros((2 * u + 1, n))  # bands[u + i − j, j] = A[i, j]
    bands[u - 1, 1:] = 1 / 6
    bands[u] = 4 / 6
    bands[u + 1, :-1] = 1 / 6
    if extrapolated:  # c_{−1} = 4c_0 − 6c_1 + 4c_2 − c_3 (and mirrored): row 0 = [8, −5, 4, −1]/6
        for j, a in enumerate((8 / 6, -5 / 6, 4 / 6, -1 / 6)):
            bands[u - j, j] = a
            bands[u + j, n - 1 - j] = a
    else:  # clamped: c_{−1} = c_0, c_n = c_{n−1}
        bands[u, 0] += 1 / 6
        bands[u, -1] += 1 / 6
    c = solve_banded((u, u), bands, v.reshape(n, -1)).reshape(v.shape)
    return np.moveaxis(c, 0, axis)


def _periodic(values: np.ndarray, axis: int) -> np.ndarray:
    v = np.moveaxis(values, axis, -1)
    n = v.shape[-1]
    kernel = np.zeros(n)
    kernel[0] = 4 / 6
    kernel[1 % n] += 1 / 6
    kernel[-1 % n] += 1 / 6
    c = np.fft.irfft(np.fft.rfft(v, axis=-1) / np.fft.rfft(kernel), n=n, axis=-1)
    c = np.concatenate([c[..., n - PERIODIC_PAD :], c, c[..., :PERIODIC_PAD]], axis=-1)
    return np.moveaxis(c, -1, axis)


def prefilter(
    values, *, axes: tuple[int, ...] | None = None, periodic: tuple[int, ...] = (), extrapolated: tuple[int, ...] = ()
) -> np.ndarray:
    """The B-spline coefficients (float64) that interpolate ``values`` at its nodes along ``axes`` (default every
    axis). The ends: clamped (``c_{−1} = c_0``, what ``eval_cubic`` does beyond a texture's edge); along the
    ``extrapolated`` axes, the coefficients beyond each end continue the cubic through the four end ones (exact for
    a cubic polynomial: meant for axes :func:`extend`-ed with ghost nodes, which keep evaluation off the ends);
    along the ``periodic`` axes periodic (their nodes ``0 … n−1`` one period, the returned axis ``n +
    2·``:data:`PERIODIC_PAD` long: node j at index ``j + PERIODIC_PAD``)."""
    c = np.asarray(values, float)
    wrapped = {a % c.ndim for a in periodic}
    cubic = {a % c.ndim for a in extrapolated}
    for axis in range(c.ndim) if axes is None else sorted({a % c.ndim for a in axes} | wrapped | cubic):
        c = _periodic(c, axis) if axis in wrapped else _solve(c, axis, axis in cubic)
    return c


def weights(x, n: int) -> np.ndarray:
    """``(len(x), n)``: the weights of the n coefficients at continuous indices x, the clamped ends folded in."""
    x = np.atleast_1d(np.asarray(x, float))
    first = np.floor(x).astype(int) - 1
    out = np.zeros((len(x), n))
    rows = np.arange(len(x))
    for step in range(4):
        k = first + step
        np.add.at(out, (rows, np.clip(k, 0, n - 1)), basis(x - k))
    return out


def on_grid(coefficients, points) -> np.ndarray:
    """The spline of ``coefficients`` on the tensor grid of continuous indices ``points`` (one 1-D array per axis,
    in the coefficients' index units, or None to keep an axis as it is): ``Σ_k c_k Π_a B₃(x_a − k_a)``, clamped
    ends — what ``eval_cubic`` returns."""
    out = np.asarray(coefficients, float)
    for axis, x in enumerate(points):
        if x is None:
            continue
        out = np.moveaxis(np.tensordot(weights(x, out.shape[axis]), np.moveaxis(out, axis, 0), axes=(1, 0)), 0, axis)
    return out


def extend(values, ghosts: int = GHOSTS, axis: int = 0) -> np.ndarray:
    """``values`` with ``ghosts`` nodes added before and after along ``axis``, extrapolated by the polynomial of
    degree ``min(n − 1, 3)`` through the end nodes (so the spline's ends follow the function's slope and curvature;
    clamped coefficients alone would flatten it there, an O(h) error)."""
    v = np.moveaxis(np.asarray(values, float), axis, 0)
    n = v.shape[0]
    d = min(n - 1, 3)
    nodes = np.arange(d + 1)

    def lagrange(x):
        return np.array([np.prod([(x - b) / (a - b) for b in nodes if b != a]) for a in nodes])

    before = [np.tensordot(lagrange(-g), v[: d + 1], axes=(0, 0)) for g in range(ghosts, 0, -1)]
    after = [np.tensordot(lagrange(-g), v[::-1][: d + 1], axes=(0, 0)) for g in range(1, ghosts + 1)]
    out = np.concatenate(
        [np.asarray(before).reshape(ghosts, *v.shape[1:]), v, np.asarray(after).reshape(ghosts, *v.shape[1:])]
    )
    return np.moveaxis(out, 0, axis)


def runs(log_mu, rtol: float = 1e-6) -> list[int]:
    """The breaks ``[0, …, n − 1]`` of a ladder into maximal runs of equal ln-μ steps (to ``rtol``): each run is
    interpolated by its own spline (:func:`runs_coefficients`)."""
    x = np.asarray(log_mu, float)
    breaks = [0]
    for k in range(1, len(x) - 1):
        if not is_uniform(x[breaks[-1] : k + 2], rtol):
            breaks.append(k)
    return breaks + [len(x) - 1] if len(x) > 1 else [0, 0]


def runs_coefficients(values, breaks, *, periodic: tuple[int, ...] = (), extrapolated: tuple[int, ...] = ()):
    """The B-spline coefficients of ``values`` (levels along axis 0) run by run: for each run ``[a, b]`` of
    ``breaks`` the levels ``a … b`` (the break levels in both of their runs), :func:`extend`-ed by :data:`GHOSTS`
    levels each side and prefiltered along every axis (axis 0 and ``extrapolated`` with the cubic closure,
    ``periodic`` ones periodic, the others clamped); the blocks concatenated along axis 0, run r's level ``a + j``
    at index ``Σ_{q<r}(n_q + 2·GHOSTS) + GHOSTS + j``."""
    v = np.asarray(values, float)
    blocks = [extend(v[a : b + 1]) for a, b in zip(breaks[:-1], breaks[1:])]
    return np.concatenate(
        [prefilter(block, periodic=periodic, extrapolated=(0, *extrapolated)) for block in blocks], axis=0
    )


def is_uniform(x, rtol: float = 1e-6) -> bool:
    """Whether the points ``x`` (increasing) are evenly spaced, to ``rtol`` of their step."""
    d = np.diff(np.asarray(x, float))
    return len(d) == 0 or bool(np.all(np.abs(d - d.mean()) <= rtol * abs(d.mean())))
