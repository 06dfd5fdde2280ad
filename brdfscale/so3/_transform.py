"""Forward and inverse SO(3) Fourier transforms on the Kostelec–Rockmore grid, and synthesis
at arbitrary rotations.

Coefficients (seed §5, docs/conventions.md §3):

    f^J_{MM'} = (2J+1)/(8π²) ∫ f(Γ) D^J_{MM'}(Γ)* dΓ,      f(Γ) = Σ_J Σ_{MM'} f^J_{MM'} D^J_{MM'}(Γ),

stored as a padded complex array ``c[..., J, L + M, N + M']`` of shape ``(..., B, 2L+1, 2N+1)``:
degrees J < B (the band limit), ``|M| ≤ L`` and ``|M'| ≤ N`` (``L, N ≤ B − 1``; smaller values
compute only the orders a query needs), zeros where ``|M| > J`` or ``|M'| > J``. Block J is
``c[..., J, L−J:L+J+1, N−J:N+J+1]`` when ``J ≤ L, N``.

Algorithm. With the Fourier form of d (see :mod:`._wigner`),
``d^J_{MM'}(β) = σ_{MM'} Σ_{m≤J} ε_m X^J_{mM} X^J_{mM'} t_{MM'}(mβ)`` (t = cos or sin by the
parity of M − M'), a transform factors into

1. a fold of the samples about β = π/2 (the grid is symmetric and cos/sin of m(π − β) are
   ±cos/sin mβ), then FFTs over α and γ on contiguous slabs, one β at a time (O(B³ log B));
2. a cosine/sine series in β: two dense (B × B) matrix products on the folded halves
   (O(B⁴), BLAS; :func:`_beta_matrices`);
3. the degree–frequency contraction ``T_{MM'}(m) = Σ_J X^J_{mM} X^J_{mM'} f^J_{MM'}`` and
   its transpose, on the four sign quadrants of (M, M') at once and blocked for the cache
   (:mod:`._contraction`; O(B⁴) with a small constant, memory O(B³)).

Forward and inverse are exact for band-limited functions (the β quadrature is exact for
products of d's with J < B): round trip ≤ 1e-11 at B = 64 in float64 (tests, benchmark).
All functions are jit-compiled, differentiable and batched over leading dimensions.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float, Shaped

from .._errors import InvalidInputError
from .._validation import as_float_array
from ._contraction import degree_to_frequency, frequency_to_degree, kernel_tables, MIXED, Plan, plan, QUADRANTS
from ._grid import check_band_limit, grid, quadrature_weights
from ._wigner import euler_angles, fourier_weights, parity_sign


__all__ = ["forward", "inverse", "synthesize", "analyse_points", "band_orders"]


def band_orders(coefficients) -> tuple[int, int, int]:
    """``(B, L, N)`` of a coefficient array of shape (..., B, 2L+1, 2N+1); validates it."""
    shape = jnp.shape(coefficients)
    if len(shape) < 3 or shape[-2] % 2 == 0 or shape[-1] % 2 == 0:
        raise InvalidInputError(
            f"SO(3) coefficients must have shape (..., B, 2L+1, 2N+1) (degree J, order M + L, order "
            f"M' + N); got shape {shape}."
        )
    B, L, N = shape[-3], (shape[-2] - 1) // 2, (shape[-1] - 1) // 2
    check_band_limit(B, "the band limit B (coefficients.shape[-3])")
    if L > B - 1 or N > B - 1:
        raise InvalidInputError(f"orders must satisfy L, N ≤ B − 1 = {B - 1}; got L = {L}, N = {N} from shape {shape}.")
    return B, L, N


# --- the quadrant layout of ._contraction ----------------------------------------------------
# An order axis is either the coefficient layout M = −K … K ("orders") or the FFT layout of
# length 2B, M at index M mod 2B ("fft"). Splitting and merging use slices and reversals
# only (no gathers), so that XLA fuses each into one pass over the data.
def _signed(z, axis: int, K: int, layout: str):
    """The entries at +μ and at −μ (μ = 0 … K) along ``axis``."""
    take = lambda start, stop: jax.lax.slice_in_dim(z, start, stop, axis=axis)
    if layout == "orders":
        return take(K, 2 * K + 1), jnp.flip(take(0, K + 1), axis)
    n = z.shape[axis]
    return take(0, K + 1), jnp.concatenate([take(0, 1), jnp.flip(take(n - K, n), axis)], axis)


def _unsigned(plus, minus, axis: int, layout: str, size: int):
    """The inverse of :func:`_signed`: an order axis of ``size`` from the +μ and −μ parts
    (zeros at orders beyond K in the FFT layout)."""
    K = plus.shape[axis] - 1
    rest = jnp.flip(jax.lax.slice_in_dim(minus, 1, K + 1, axis=axis), axis)
    if layout == "orders":
        return jnp.concatenate([rest, plus], axis)
    zeros = jnp.zeros(plus.shape[:axis] + (size - 2 * K - 1,) + plus.shape[axis + 1 :], plus.dtype)
    return jnp.concatenate([plus, zeros, rest], axis)


def _split(z, L: int, N: int, layout: str, columns: int):
    """Complex ``(X, n, R, C)`` (orders M along R, M' along C, in ``layout``) → the quadrant
    layout ``(X, L+1, columns, ch)``, real, channels (quadrant, re/im, n)."""
    parts = {}
    for sr, r in zip((1, -1), _signed(z, 2, L, layout)):
        for sc, q in zip((1, -1), _signed(r, 3, N, layout)):
            parts[sr, sc] = q
    q = jnp.stack([parts[s] for s in QUADRANTS], axis=-1)  # (X, n, L+1, N+1, 4)
    r = jnp.stack([jnp.real(q), jnp.imag(q)], axis=-1)  # (X, n, L+1, N+1, 4, 2)
    r = jnp.moveaxis(r, 1, -1)
    r = r.reshape(r.shape[:3] + (-1,))
    return jnp.pad(r, ((0, 0), (0, 0), (0, columns - r.shape[2]), (0, 0)))


def _merge(r, n: int, N: int, layout: str, size_r: int, size_c: int):
    """The quadrant layout ``(X, L+1, N_p, ch)`` → complex ``(X, n, R, C)`` (the inverse of
    :func:`_split`; R has ``size_r`` and C ``size_c`` entries)."""
    r = r[:, :, : N + 1].reshape(r.shape[:2] + (N + 1, 4, 2, n))
    z = r[..., 0, :] + 1j * r[..., 1, :]  # (X, L+1, N+1, 4, n)
    q = dict(zip(QUADRANTS, jnp.transpose(z, (3, 0, 4, 1, 2))))  # each (X, n, L+1, N+1)
    plus, minus = (_unsigned(q[sr, 1], q[sr, -1], 3, layout, size_c) for sr in (1, -1))
    return _unsigned(plus, minus, 2, layout, size_r)


def _mixed_sign(size: int, channels: int, dtype):
    """``(−1)^x`` on the mixed-quadrant channels, 1 elsewhere: shape (size, 1, 1, channels)."""
    mixed = np.repeat(MIXED, channels // 4)
    sign = np.where(mixed[None, :] & (np.arange(size)[:, None] % 2 == 1), -1.0, 1.0)
    return jnp.asarray(sign[:, None, None, :], dtype)


def _cosine_frequencies(p: Plan, m_size: int, columns: int):
    """Where frequency m meets order pair (μ, μ') of the same parity as m + μ + μ' even:
    ``(m, L+1, N_p, 1)`` booleans (:func:`_beta_matrices`)."""
    m = np.arange(m_size)[:, None, None]
    mu = np.arange(p.L + 1)[None, :, None]
    mup = np.arange(columns)[None, None, :]
    return jnp.asarray(((m + mu + mup) % 2 == 0)[..., None])


def _sigma(L: int, N: int, dtype):
    _, sigma = parity_sign(np.arange(-L, L + 1), np.arange(-N, N + 1))
    return jnp.asarray(sigma, dtype)


def _degree_normalisation(B, dtype):
    return jnp.asarray((2 * np.arange(B) + 1) / (8 * np.pi**2), dtype)


def _real_dtype(x):
    return jnp.finfo(jnp.result_type(x)).dtype


def _batch(z, core: int):
    """Leading batch shape and the array reshaped to (n, *core)."""
    batch = z.shape[: z.ndim - core]
    return batch, z.reshape((-1,) + z.shape[z.ndim - core :])


# --- forward ----------------------------------------------------------------------------------
def _analysis(p: Plan, tables, phi, n: int, dtype):
    """Quadrant-layout β-Fourier coefficients φ[m, μ, μ', ch] → complex f^J_{MM'} (n, B, 2L+1, 2N+1)."""
    phi = phi * _mixed_sign(p.B, phi.shape[-1], dtype)
    f = frequency_to_degree(p, tables, phi) * _mixed_sign(p.B, phi.shape[-1], dtype)
    c = jnp.moveaxis(_merge(f, n, p.N, "orders", 2 * p.L + 1, 2 * p.N + 1), 1, 0)  # (n, J, M, M')
    return c * _sigma(p.L, p.N, dtype) * _degree_normalisation(p.B, dtype)[:, None, None]


@functools.partial(jax.jit, static_argnames=("p",))
def _forward(samples, tables, wa, wb, *, p: Plan):
    B, rdt = p.B, tables[0].dtype
    batch, s = _batch(samples.astype(jnp.result_type(rdt, 1j)), 3)
    # (1) fold about β = π/2 (β_{2B−1−k} = π − β_k, equal weights): f(β_k) ± f(π − β_k), k < B,
    # one β per slab; then Σ_a Σ_g e^{+iMα_a} e^{+iM'γ_g} (π/B)², an inverse FFT times (2B)²
    reflected = jnp.flip(s[:, :, B:], 2)
    folded = jnp.stack([s[:, :, :B] + reflected, s[:, :, :B] - reflected])  # (±, n, a, k, g)
    F = jnp.fft.ifft2(jnp.transpose(folded, (0, 3, 1, 2, 4)), axes=(3, 4)) * (4 * np.pi**2)
    r = _split(F.reshape((2 * B,) + F.shape[2:]), p.L, p.N, "fft", p.columns)  # (±k, L+1, N_p, ch)
    # (2) the β quadrature (see _beta_matrices)
    A = jnp.tensordot(wa, r[:B], axes=1)
    Bm = jnp.tensordot(wb, r[B:], axes=1)
    phi = jnp.where(_cosine_frequencies(p, B, p.columns), A, Bm)
    # (3) the degree–frequency contraction
    c = _analysis(p, tables, phi, s.shape[0], rdt)
    return c.reshape(batch + c.shape[1:])


# --- inverse ----------------------------------------------------------------------------------
def _fourier_series(p: Plan, tables, coefficients):
    """``σ_{MM'} Σ_J X X f^J`` in the quadrant layout (m, L+1, N_p, ch), the batch shape and n:
    the β-Fourier coefficients of ``Σ_J f^J_{MM'} d^J_{MM'}(β)``."""
    rdt = tables[0].dtype
    batch, c = _batch(coefficients * _sigma(p.L, p.N, rdt), 3)
    g = _split(jnp.moveaxis(c, 1, 0), p.L, p.N, "orders", p.columns)
    sign = _mixed_sign(p.B, g.shape[-1], rdt)
    return degree_to_frequency(p, tables, g * sign) * sign, batch, c.shape[0]


@functools.partial(jax.jit, static_argnames=("p",))
def _inverse(coefficients, tables, va, vb, *, p: Plan):
    B = p.B
    T, batch, n = _fourier_series(p, tables, coefficients)
    cosine = _cosine_frequencies(p, B, p.columns)
    R1 = jnp.tensordot(va, jnp.where(cosine, T, 0), axes=1)  # (B[k], …)
    R2 = jnp.tensordot(vb, jnp.where(cosine, 0, T), axes=1)
    spectrum = _merge(jnp.concatenate([R1, R2]), n, p.N, "fft", 2 * B, 2 * B)  # (2B, n, a', g')
    S = jnp.fft.fft2(spectrum, axes=(2, 3))  # Σ G e^{−iMα_a} e^{−iM'γ_g}, one β slab at a time
    S1, S2 = S[:B], S[B:]
    f = jnp.concatenate([S1 + S2, jnp.flip(S1 - S2, 0)])  # β_k and π − β_k
    f = jnp.transpose(f, (1, 2, 0, 3))  # (n, a, k, g)
    return f.reshape(batch + f.shape[1:])


def _tables(B: int, L: int, N: int, dtype):
    p = plan(B, L, N)
    return p, kernel_tables(p, dtype)


@functools.lru_cache(maxsize=32)
def _beta_matrices_f64(B: int, weighted: bool):
    _, beta, _ = grid(B)
    m = np.arange(B)
    eps = fourier_weights(B - 1)
    x = np.outer(beta[:B], m)
    even = m % 2 == 0
    a = eps * np.where(even, np.cos(x), np.sin(x))
    b = eps * np.where(even, np.sin(x), np.cos(x))
    if weighted:  # forward: (m, k)
        w = quadrature_weights(B)[:B, None]
        return (a * w).T, (b * w).T
    return a, b  # inverse: (k, m)


def _beta_matrices(B: int, dtype, weighted: bool):
    """The folded β matrices for k < B: ``ε_m (cos mβ_k if m even else sin mβ_k)`` and
    ``ε_m (sin mβ_k if m even else cos mβ_k)``, times the weights w_k for the forward.

    For order pairs with M − M' even (cosine series) the first collects the even, the second
    the odd frequencies, and the other way round for the sine series; with
    ``cos m(π−β) = (−1)^m cos mβ`` and ``sin m(π−β) = −(−1)^m sin mβ`` the half-grid sums
    ``R1 ± R2`` give the values at β_k and π − β_k (half the work of the unfolded product)."""
    return tuple(jnp.asarray(x, dtype) for x in _beta_matrices_f64(B, weighted))


def _orders(B, m_max, n_max):
    L = B - 1 if m_max is None else m_max
    N = B - 1 if n_max is None else n_max
    for name, v in (("m_max", L), ("n_max", N)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 0 <= v <= B - 1:
            raise InvalidInputError(f"{name} must be an integer in [0, B − 1 = {B - 1}] or None; got {v!r}.")
    return int(L), int(N)


def forward(
    samples: Shaped[ArrayLike, "*batch n n n"], *, m_max: int | None = None, n_max: int | None = None
) -> Complex[Array, "*batch n//2 rows cols"]:
    """SO(3) Fourier coefficients ``f^J_{MM'} = (2J+1)/(8π²) ∫ f D^{J*} dΓ`` from grid samples.

    Args:
        samples: ``f(α_a, β_k, γ_g)`` on the Kostelec–Rockmore grid of band limit B
            (:func:`grid`), axes ``[..., a, k, g]`` of ``n = 2B`` entries each; real or complex;
            float32 or float64 (other dtypes are converted to float).
        m_max, n_max: compute only orders ``|M| ≤ m_max`` and ``|M'| ≤ n_max`` (default
            B − 1: all). A function independent of γ (e.g. of the facet normal only) has
            ``n_max = 0``.

    Returns:
        Complex coefficients of shape ``(..., B, rows, cols)``, ``B = n/2``, ``rows = 2L+1``,
        ``cols = 2N+1`` with L = m_max and N = n_max (module docstring). Exact
        (to rounding) when f is band-limited to J < B.
    """
    s = jnp.asarray(samples)
    if s.ndim < 3 or not (s.shape[-1] == s.shape[-2] == s.shape[-3]) or s.shape[-1] % 2:
        raise InvalidInputError(
            f"samples must have shape (..., 2B, 2B, 2B) (Euler angles α, β, γ on the Kostelec–Rockmore "
            f"grid); got shape {s.shape}."
        )
    B = check_band_limit(s.shape[-1] // 2, "B (half the grid size)")
    if not (jnp.issubdtype(s.dtype, jnp.floating) or jnp.issubdtype(s.dtype, jnp.complexfloating)):
        s = s.astype(jnp.result_type(float))
    L, N = _orders(B, m_max, n_max)
    rdt = _real_dtype(s)
    p, tables = _tables(B, L, N, rdt)
    return _forward(s, tables, *_beta_matrices(B, rdt, weighted=True), p=p)


def _coefficients(coefficients):
    c = jnp.asarray(coefficients)
    if not (jnp.issubdtype(c.dtype, jnp.floating) or jnp.issubdtype(c.dtype, jnp.complexfloating)):
        c = c.astype(jnp.result_type(float))
    B, L, N = band_orders(c)
    return c.astype(jnp.result_type(c.dtype, 1j)), B, L, N


def inverse(coefficients: Shaped[ArrayLike, "*batch B rows cols"]) -> Complex[Array, "*batch 2*B 2*B 2*B"]:
    """``f(α_a, β_k, γ_g) = Σ_J Σ_{MM'} f^J_{MM'} D^J_{MM'}`` on the Kostelec–Rockmore grid.

    The inverse of :func:`forward`; ``coefficients`` of shape ``(..., B, 2L+1, 2N+1)`` (module
    docstring), complex (real ones are taken as complex, other dtypes converted). Returns complex
    samples with axes ``[..., a, k, g]`` (take ``.real`` for a real function).
    """
    c, B, L, N = _coefficients(coefficients)
    rdt = _real_dtype(c)
    p, tables = _tables(B, L, N, rdt)
    return _inverse(c, tables, *_beta_matrices(B, rdt, weighted=False), p=p)


@functools.partial(jax.jit, static_argnames=("p", "chunk"))
def _synthesize(coefficients, tables, alpha, beta, gamma, *, p: Plan, chunk):
    B, L, N, rdt = p.B, p.L, p.N, tables[0].dtype
    T, batch, n = _fourier_series(p, tables, coefficients)
    T = jnp.moveaxis(_merge(T, n, N, "orders", 2 * L + 1, 2 * N + 1), 1, 0)
    T = T.reshape(batch + T.shape[1:])  # (..., m, 2L+1, 2N+1) complex
    odd, _ = parity_sign(np.arange(-L, L + 1), np.arange(-N, N + 1))
    even_part = jnp.where(jnp.asarray(odd), 0.0, T)
    odd_part = jnp.where(jnp.asarray(odd), T, 0.0)
    m = jnp.arange(B, dtype=rdt)
    eps = jnp.asarray(fourier_weights(B - 1), rdt)
    M = jnp.arange(-L, L + 1, dtype=rdt)
    Mp = jnp.arange(-N, N + 1, dtype=rdt)

    def at(angles):
        a, b, g = angles
        ca, sa = eps * jnp.cos(b[:, None] * m), eps * jnp.sin(b[:, None] * m)
        ea = jnp.exp(-1j * a[:, None] * M)
        eg = jnp.exp(-1j * g[:, None] * Mp)
        return jnp.einsum("...mab,qm,qa,qb->...q", even_part, ca, ea, eg, optimize="optimal") + jnp.einsum(
            "...mab,qm,qa,qb->...q", odd_part, sa, ea, eg, optimize="optimal"
        )

    n = alpha.shape[0]
    pad = (-n) % chunk
    angles = [jnp.pad(x, (0, pad)).reshape(-1, chunk) for x in (alpha, beta, gamma)]
    out = jax.lax.map(at, angles)  # (n_chunks, ..., chunk)
    out = jnp.moveaxis(out, 0, -2).reshape(out.shape[1:-1] + (-1,))
    return out[..., :n]


def synthesize(
    coefficients: Shaped[ArrayLike, "*batch B rows cols"],
    alpha: Float[ArrayLike, "*#query"],
    beta: Float[ArrayLike, "*#query"],
    gamma: Float[ArrayLike, "*#query"],
    *,
    chunk: int = 256,
) -> Complex[Array, "..."]:
    """``f(Γ) = Σ_J Σ_{MM'} f^J_{MM'} D^J_{MM'}(α, β, γ)`` at arbitrary rotations, no grid.

    ``coefficients`` as for :func:`inverse`; the angles broadcast to one query shape. The result
    has shape ``batch + query`` (two variadic parts, which one jaxtyping shape cannot name).

    Cost: one O(B⁴) contraction shared by all queries, then O(B (2L+1)(2N+1)) per query;
    queries are processed ``chunk`` at a time (memory O(chunk · B · (2L+1))). Use
    :func:`matrix_to_euler` for rotations given as matrices.
    """
    c, B, L, N = _coefficients(coefficients)
    rdt = _real_dtype(c)
    a, b, g = (x.astype(rdt) for x in euler_angles(alpha, beta, gamma))
    qshape = a.shape
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise InvalidInputError(f"chunk must be a positive integer; got {chunk!r}.")
    p, tables = _tables(B, L, N, rdt)
    out = _synthesize(c, tables, a.reshape(-1), b.reshape(-1), g.reshape(-1), p=p, chunk=chunk)
    return out.reshape(out.shape[:-1] + qshape)


@functools.partial(jax.jit, static_argnames=("p",))
def _analyse_points(tables, alpha, beta, gamma, weights, *, p: Plan):
    B, L, N, rdt = p.B, p.L, p.N, tables[0].dtype
    odd, _ = parity_sign(np.arange(-L, L + 1), np.arange(-N, N + 1))
    m = jnp.arange(B, dtype=rdt)
    eps = jnp.asarray(fourier_weights(B - 1), rdt)
    ea = jnp.exp(1j * alpha[:, None] * jnp.arange(-L, L + 1, dtype=rdt))
    eg = jnp.exp(1j * gamma[:, None] * jnp.arange(-N, N + 1, dtype=rdt))
    wc = (weights[:, None] * eps * jnp.cos(beta[:, None] * m)).astype(ea.dtype)
    ws = (weights[:, None] * eps * jnp.sin(beta[:, None] * m)).astype(ea.dtype)
    phi_c = jnp.einsum("qm,qa,qb->mab", wc, ea, eg, optimize="optimal")
    phi_s = jnp.einsum("qm,qa,qb->mab", ws, ea, eg, optimize="optimal")
    phi = jnp.where(jnp.asarray(odd), phi_s, phi_c)
    phi = _split(phi[:, None], L, N, "orders", p.columns)
    return _analysis(p, tables, phi, 1, rdt)[0]


def analyse_points(
    alpha: Float[ArrayLike, "*#query"],
    beta: Float[ArrayLike, "*#query"],
    gamma: Float[ArrayLike, "*#query"],
    B: int,
    *,
    weights: Float[ArrayLike, "*query"] | None = None,
    m_max: int | None = None,
    n_max: int | None = None,
) -> Complex[Array, "B rows cols"]:
    """Coefficients of the weighted point set ``Σ_q w_q δ(Γ_q)``: ``(2J+1)/(8π²) Σ_q w_q D^J(Γ_q)*``.

    The angles broadcast to one shape, one rotation per entry, and ``weights`` has one entry per
    rotation. The result has shape ``(B, 2L+1, 2N+1)`` with L = m_max and N = n_max.

    The adjoint of :func:`synthesize`. With weights 1/n this is the exact SO(3) transform
    of the empirical distribution of n rotations (e.g. facet frames) — no binning; default
    weights are 1/n.
    """
    B = check_band_limit(B)
    L, N = _orders(B, m_max, n_max)
    a, b, g = (x.reshape(-1) for x in euler_angles(alpha, beta, gamma))
    if a.shape[0] == 0:
        raise InvalidInputError("analyse_points needs at least one rotation.")
    rdt = _real_dtype(a)
    w = (
        jnp.full(a.shape, 1.0 / a.shape[0], rdt)
        if weights is None
        else as_float_array(weights, "weights").reshape(-1).astype(rdt)
    )
    if w.shape != a.shape:
        raise InvalidInputError(f"weights must have one entry per rotation ({a.shape[0]}); got {w.shape[0]}.")
    p, tables = _tables(B, L, N, rdt)
    return _analyse_points(tables, a, b, g, w, p=p)
