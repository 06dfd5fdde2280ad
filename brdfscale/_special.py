"""Bessel functions J0, J1, K0 and x·K1(x) for real arguments, in pure JAX.

JAX ships no K0/K1 and its ``bessel_jn`` recurrence is unusable here (NaNs for small
arguments, O(1) errors beyond x ≈ 1e3), so these are evaluated from their classical
integral representations with quadratures whose error is provably below float64 rounding:

* ``J_n(x) = (1/2π) ∫_0^{2π} cos(n τ − x sin τ) dτ`` for ``|x| ≤ 25``: the trapezoidal rule
  on a periodic analytic integrand; with N nodes its error is ``≈ |J_{N−n}(x)| ≤
  (e x / 2(N−n))^{N−n}``, below 1e-17 for N = 96 at x = 25.
* The Hankel asymptotic expansion (DLMF 10.17.3) for ``|x| > 25``: the terms decrease
  until ``k ≈ 2x``, so 24 terms leave a truncation error below ``e^{−50}``.
* ``K0`` and ``x K1(x)``: the ascending series (DLMF 10.31.1–2) in ``q = x²/4`` for
  ``x ≤ 2``, where 13 terms reach 1e-17 (Horner's rule on precomputed coefficients); for
  ``x > 2`` one Chebyshev expansion (degree 24) of the smooth ``√x eˣ K_ν(x)`` in
  ``y = 1/x ∈ [0, 1/2]``, whose value at y = 0 is the limit ``√(π/2)`` (DLMF 10.40.2). Its
  coefficients are fitted at import to the integral ``K_ν(x) = ∫_0^∞ e^{−x cosh t}
  cosh(ν t) dt`` (DLMF 10.32.9) evaluated by the trapezoidal rule, whose error for this
  double-exponentially decaying integrand is below 1e-17 with 400 nodes; nothing is copied
  from a table. Both branches are computed (as ``jnp.where`` does under ``vmap``): one each
  of log, exp and square root, a division, 24 Clenshaw steps and two 13-term Horner sums.

Derivatives are supplied analytically (``J0' = −J1``, ``J1' = J0 − J1/x``, ``K0' = −K1``,
``(x K1)' = −x K0``) through ``jax.custom_jvp``, so gradients are as accurate as values.
Accuracy against SciPy/mpmath is tested in tests/test_special.py.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

_SWITCH = 25.0
_N_TRAPEZOID_J = 96
_N_ASYMPTOTIC = 24
_XK1_SMALL = 1e-12


def _hankel_coefficients(nu: int, count: int) -> np.ndarray:
    """a_k(ν) of DLMF 10.17.1: a_k = ∏_{j=1..k} (4ν² − (2j−1)²) / (k! 8^k)."""
    out = np.ones(count)
    for k in range(1, count):
        out[k] = out[k - 1] * (4 * nu**2 - (2 * k - 1) ** 2) / (k * 8.0)
    return out


_HANKEL = {0: _hankel_coefficients(0, _N_ASYMPTOTIC), 1: _hankel_coefficients(1, _N_ASYMPTOTIC)}


def _j_trapezoid(n: int, x):
    tau = jnp.arange(_N_TRAPEZOID_J, dtype=x.dtype) * (2 * np.pi / _N_TRAPEZOID_J)
    return jnp.mean(jnp.cos(n * tau - x[..., None] * jnp.sin(tau)), axis=-1)


def _j_asymptotic(n: int, x):
    # Only called on |x| > _SWITCH (elsewhere x is replaced by a safe dummy value).
    a = _HANKEL[n]
    ax = jnp.abs(x)
    inv = 1.0 / ax
    p = jnp.zeros_like(ax)
    q = jnp.zeros_like(ax)
    for k in range(_N_ASYMPTOTIC - 1, -1, -1):
        term = float(a[k]) * inv**k  # a Python float keeps the argument's dtype
        if k % 2 == 0:
            p = p + (-1) ** (k // 2) * term
        else:
            q = q + (-1) ** ((k - 1) // 2) * term
    chi = ax - (n / 2 + 0.25) * np.pi
    value = jnp.sqrt(2.0 / (np.pi * ax)) * (p * jnp.cos(chi) - q * jnp.sin(chi))
    return value * jnp.sign(x) ** n  # J_n(−x) = (−1)^n J_n(x)


def _bessel_j(n: int, x):
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    large = jnp.abs(x) > _SWITCH
    x_small = jnp.where(large, 0.0, x)
    x_large = jnp.where(large, x, 2 * _SWITCH)
    return jnp.where(large, _j_asymptotic(n, x_large), _j_trapezoid(n, x_small))


@jax.custom_jvp
def j0(x):
    """Bessel function of the first kind of order 0, ``J0(x)``, for real x."""
    return _bessel_j(0, x)


@jax.custom_jvp
def j1(x):
    """Bessel function of the first kind of order 1, ``J1(x)``, for real x."""
    return _bessel_j(1, x)


@j0.defjvp
def _j0_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    return j0(x), -j1(x) * dx


@j1.defjvp
def _j1_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    # J1' = (J0 − J2)/2 avoids the 0/0 of J0 − J1/x at x = 0; J2 = 2 J1/x − J0.
    return j1(x), 0.5 * (j0(x) - _j2(x)) * dx


def _j2(x):
    safe = jnp.where(jnp.abs(x) < 1e-4, 1.0, x)
    series = x**2 / 8 - x**4 / 96
    return jnp.where(jnp.abs(x) < 1e-4, series, 2 * j1(safe) / safe - j0(safe))


@jax.custom_jvp
def jinc(x):
    """``2 J1(x) / x`` with its limit 1 at x = 0: the transform of a uniform disk."""
    x = jnp.asarray(x)
    small = jnp.abs(x) < 1.0
    safe = jnp.where(small, 1.0, x)
    return jnp.where(small, _jinc_series(x), 2 * j1(safe) / safe)


def _jinc_series(x):
    """``2 J1(x)/x = Σ_k (−x²/4)^k / (k! (k+1)!)``; 12 terms reach 1e-20 for |x| < 1."""
    term = jnp.ones_like(x)
    total = term
    for k in range(1, 12):
        term = term * (-(x**2) / 4) / (k * (k + 1))
        total = total + term
    return total


@jinc.defjvp
def _jinc_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    # d/dx [2 J1(x)/x] = −2 J2(x)/x = −x · (jinc-like J2 term); series near 0.
    small = jnp.abs(x) < 1e-3
    safe = jnp.where(small, 1.0, x)
    series = -x / 4 + x**3 / 48 - x**5 / 1536
    return jinc(x), jnp.where(small, series, -2 * _j2(safe) / safe) * dx


_K_SERIES_TERMS = 13  # x ≤ 2 (q ≤ 1): terms k = 0…12; the first left out, k = 13, is ≤ H₁₃/(13!)² < 1e-19
_K_CHEB_DEGREE = 24
_K_SWITCH = 2.0


def _k_integral_numpy(nu: int, x: np.ndarray) -> np.ndarray:
    """``√x eˣ K_ν(x)`` by the trapezoidal rule on DLMF 10.32.9 (NumPy, for the fit only).

    ``cosh t − 1`` is written ``2 sinh²(t/2)``, which keeps full relative precision at the
    small t that dominate for large x."""
    T = np.arccosh(1.0 + 45.0 / x)
    t = T[:, None] * np.linspace(0.0, 1.0, 401)[None, :]
    f = np.exp(-x[:, None] * 2.0 * np.sinh(t / 2) ** 2) * np.cosh(nu * t)
    h = T / 400
    return np.sqrt(x) * h * (f.sum(axis=1) - 0.5 * (f[:, 0] + f[:, -1]))


def _chebyshev_in_inverse_x(nu: int) -> np.ndarray:
    """Chebyshev coefficients of ``√x eˣ K_ν(x)`` in ``y = 1/x`` on ``[0, 1/2]`` (all x ≥ 2).

    Least squares on 401 Chebyshev–Lobatto points, the one at y = 0 taking the limit
    ``√(π/2)`` (DLMF 10.40.2), so that the fit is not extrapolated towards x → ∞."""
    y = 0.25 * (1.0 - np.cos(np.pi * np.arange(401) / 400))
    f = np.empty_like(y)
    f[0] = math.sqrt(math.pi / 2)
    f[1:] = _k_integral_numpy(nu, 1.0 / y[1:])
    return np.polynomial.chebyshev.Chebyshev.fit(y, f, _K_CHEB_DEGREE, domain=[0.0, 1 / _K_SWITCH]).coef


def _series_coefficients() -> dict[str, np.ndarray]:
    """Coefficients in ``q = x²/4`` of the ascending series (DLMF 10.31.1–2):

    ``K0(x) = −(ln(x/2) + γ) Σ q^k/(k!)² + Σ H_k q^k/(k!)²``,
    ``x K1(x) = 1 + (x²/2) ln(x/2) Σ q^k/(k!(k+1)!) − q Σ (ψ(k+1) + ψ(k+2)) q^k/(k!(k+1)!)``,
    with ``H_k`` the harmonic numbers and ``ψ(k+1) + ψ(k+2) = 2H_k + 1/(k+1) − 2γ``."""
    k = np.arange(_K_SERIES_TERMS)
    harmonic = np.concatenate([[0.0], np.cumsum(1.0 / np.arange(1, _K_SERIES_TERMS))])
    square = np.array([1.0 / math.factorial(int(j)) ** 2 for j in k])
    pair = np.array([1.0 / (math.factorial(int(j)) * math.factorial(int(j) + 1)) for j in k])
    psi = 2 * harmonic + 1.0 / (k + 1) - 2 * np.euler_gamma
    return {"i0": square, "k0": harmonic * square, "i1": pair, "xk1": psi * pair}


_K_CHEB = {0: _chebyshev_in_inverse_x(0), 1: _chebyshev_in_inverse_x(1)}
_K_SERIES = _series_coefficients()


def _horner(coef: np.ndarray, q):
    total = jnp.full_like(q, float(coef[-1]))
    for c in coef[-2::-1]:
        total = total * q + float(c)
    return total


def _clenshaw(coef: np.ndarray, y, lo: float, hi: float):
    t = (2 * y - (lo + hi)) / (hi - lo)
    b1 = jnp.zeros_like(y)
    b2 = jnp.zeros_like(y)
    for c in coef[:0:-1]:
        b1, b2 = 2 * t * b1 - b2 + float(c), b1
    return t * b1 - b2 + float(coef[0])


def _k_series(nu: int, x):
    """``K0(x)`` (ν = 0) or ``x K1(x)`` (ν = 1) from the ascending series, for 0 < x ≤ 2."""
    q = x * x / 4
    log_half = jnp.log(x / 2)
    if nu == 0:
        return -(log_half + np.euler_gamma) * _horner(_K_SERIES["i0"], q) + _horner(_K_SERIES["k0"], q)
    return 1 + 2 * q * log_half * _horner(_K_SERIES["i1"], q) - q * _horner(_K_SERIES["xk1"], q)


def _as_float(x):
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def _k_branches(nu: int, x):
    """``K0(x)`` or ``x K1(x)`` for x > 0: the series up to x = 2, ``e^{−x}/√x`` times the
    Chebyshev expansion in 1/x beyond (one expansion for all x > 2)."""
    small = x <= _K_SWITCH
    xs = jnp.where(small, x, 1.0)
    xl = jnp.where(small, 2 * _K_SWITCH, x)
    scaled = _clenshaw(_K_CHEB[nu], 1.0 / xl, 0.0, 1 / _K_SWITCH)  # √x eˣ K_ν(x)
    large = scaled * jnp.exp(-xl) * (jnp.sqrt(xl) if nu == 1 else jax.lax.rsqrt(xl))
    return jnp.where(small, _k_series(nu, xs), large)


@jax.custom_jvp
def k0(x):
    """Modified Bessel function of the second kind of order 0, ``K0(x)``, for x > 0."""
    return _k_branches(0, _as_float(x))


@jax.custom_jvp
def xk1(x):
    """``x K1(|x|)``, an even function of x with value 1 at x = 0.

    For the GGX/Student-t slope statistics this is the characteristic function itself:
    ``S(W) = α|W| K1(α|W|)``.
    """
    x = jnp.abs(_as_float(x))
    small = x < _XK1_SMALL
    safe = jnp.where(small, 1.0, x)
    return jnp.where(small, 1.0, _k_branches(1, safe))


@k0.defjvp
def _k0_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    x = _as_float(x)
    return k0(x), -xk1(x) / x * dx


@xk1.defjvp
def _xk1_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    x = _as_float(x)
    ax = jnp.abs(x)
    # (x K1(x))' = −x K0(x) for x > 0, odd continuation; → 0 at x = 0.
    safe = jnp.where(ax < _XK1_SMALL, 1.0, ax)
    derivative = jnp.where(ax < _XK1_SMALL, 0.0, -x * k0(safe))
    return xk1(x), derivative * dx
