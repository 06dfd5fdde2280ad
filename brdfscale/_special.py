"""Bessel functions J0, J1, K0 and x·K1(x) for real arguments, in pure JAX.

JAX ships no K0/K1 and its ``bessel_jn`` recurrence is unusable here (NaNs for small
arguments, O(1) errors beyond x ≈ 1e3), so these are evaluated from their classical
integral representations with quadratures whose error is provably below float64 rounding:

* ``J0``, ``J1`` for ``|x| ≤ 8``: one Chebyshev series in ``x/8`` each (degree 34, even;
  degree 37, odd), fitted at import to the integral ``J_n(x) = (1/2π) ∫_0^{2π} cos(n τ − x
  sin τ) dτ`` evaluated by the trapezoidal rule on 96 nodes (a periodic analytic integrand:
  error ``≈ (e x / 2(96−n))^{96−n}``, below 1e-40 at x = 8).
* For ``|x| > 8`` the modulus–phase form ``J_n(x) = √(2/πx) (P_n cos χ − Q_n sin χ)``, ``χ =
  x − (n/2 + 1/4)π`` (DLMF 10.17.3), with ``P_n``, ``Q_n`` smooth in ``y = 8/x ∈ (0, 1]``: one
  Chebyshev series (degree 20) each, fitted at import to the Hankel asymptotic expansion
  where x ≥ 25 (24 terms: error below e^{−50}) and to SciPy's ``J_n``, ``Y_n`` for 8 ≤ x < 25;
  ``cos χ``, ``sin χ`` are formed from ``cos x`` and ``sin x`` (no rounding of x − π/4).
  Both branches are computed (as ``jnp.where`` does under ``vmap``): about 75 multiply–adds,
  a cosine, a sine and a square root, in place of the trapezoidal rule on 96 nodes evaluated
  at run time (two trigonometric functions per node), which this replaced — the radial path
  of :func:`brdfscale.evolve` spends its time here; experiments/bench_special.py measures both.
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

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np


_J_SWITCH = 8.0  # |x| ≤ 8: Chebyshev series in x/8; beyond: modulus–phase form in 8/x
_J_TRAPEZOID_NODES = 96  # the trapezoidal rule the series are fitted to (error ≤ 1e-17 for |x| ≤ 8)
_J_SMALL_DEGREE = {0: 34, 1: 37}
_J_LARGE_DEGREE = 20
_N_ASYMPTOTIC = 24
_XK1_SMALL = 1e-12
J_TEMPORARIES = 8
"""Arrays of the argument's shape a J0/J1 evaluation holds at once (both branches, Clenshaw's
two carries, cos and sin): what :mod:`brdfscale._evolve` budgets per value."""


def _hankel_coefficients(nu: int, count: int) -> np.ndarray:
    """a_k(ν) of DLMF 10.17.1: a_k = ∏_{j=1..k} (4ν² − (2j−1)²) / (k! 8^k)."""
    out = np.ones(count)
    for k in range(1, count):
        out[k] = out[k - 1] * (4 * nu**2 - (2 * k - 1) ** 2) / (k * 8.0)
    return out


def _j_trapezoid_numpy(n: int, x: np.ndarray) -> np.ndarray:
    """``J_n(x) = (1/2π) ∫_0^{2π} cos(nτ − x sin τ) dτ`` by the trapezoidal rule (NumPy, for the fit only)."""
    tau = np.arange(_J_TRAPEZOID_NODES) * (2 * np.pi / _J_TRAPEZOID_NODES)
    return np.mean(np.cos(n * tau - x[:, None] * np.sin(tau)), axis=-1)


def _modulus_phase_numpy(n: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """P_n, Q_n of ``J_n(x) = √(2/πx) (P cos χ − Q sin χ)``, ``χ = x − (n/2 + 1/4)π`` (DLMF
    10.17.3): for x ≥ 25 the Hankel expansion (24 terms: error below e^{−50}); for 8 ≤ x < 25
    from SciPy's J_n and Y_n (``P = √(πx/2)(J cos χ + Y sin χ)``, ``Q = √(πx/2)(Y cos χ − J sin χ)``)."""
    import scipy.special

    a = _hankel_coefficients(n, _N_ASYMPTOTIC)
    far = x >= 25.0
    xf = np.where(far, x, 25.0)
    p = sum((-1) ** (k // 2) * a[k] / xf**k for k in range(0, _N_ASYMPTOTIC, 2))
    q = sum((-1) ** ((k - 1) // 2) * a[k] / xf**k for k in range(1, _N_ASYMPTOTIC, 2))
    xn = np.where(far, 25.0, x)
    chi = xn - (n / 2 + 0.25) * np.pi
    scale = np.sqrt(np.pi * xn / 2)
    j, y = scipy.special.jv(n, xn), scipy.special.yv(n, xn)
    return (
        np.where(far, p, scale * (j * np.cos(chi) + y * np.sin(chi))),
        np.where(far, q, scale * (y * np.cos(chi) - j * np.sin(chi))),
    )


def _j_series() -> dict:
    """The Chebyshev coefficients of both branches, least-squares fitted at import on 1000
    Chebyshev points (the fit averages the data's rounding; tests/test_special.py checks the
    result against SciPy and 30-digit mpmath). J0 is even and J1 odd in x/8: the other
    parity's coefficients are set to exactly zero."""
    from numpy.polynomial import chebyshev

    t = np.cos(np.pi * (np.arange(1000) + 0.5) / 1000)
    out = {}
    for n in (0, 1):
        small = chebyshev.chebfit(t, _j_trapezoid_numpy(n, _J_SWITCH * t), _J_SMALL_DEGREE[n])
        small[(1 - n) :: 2] = 0.0
        y = (t + 1) / 2  # 8/x ∈ (0, 1]; y = 0 is x = ∞, where P = 1 and Q = 0
        P, Q = _modulus_phase_numpy(n, _J_SWITCH / y)
        out[n] = (small, chebyshev.chebfit(t, P, _J_LARGE_DEGREE), chebyshev.chebfit(t, Q, _J_LARGE_DEGREE))
    return out


_J_SERIES = _j_series()
_SQRT_HALF = math.sqrt(0.5)


def _bessel_j(n: int, x):
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return _bessel_j_compiled(n, x)


# π/2 in three parts for Cody–Waite reduction: C1 keeps the leading 27 significant bits of
# fl(π/2) (k·C1 is exact for |k| < 2^26, i.e. x < 1e8), C2 = fl(π/2) − C1 exactly (26 bits: k·C2
# exact too), C3 = π/2 − fl(π/2) = (π − fl(π))/2 (the classic 6.123233995736766e-17)
_C1 = float(np.array([np.float64(math.pi / 2).view(np.int64) & ~np.int64((1 << 26) - 1)]).view(np.float64)[0])
_C2 = math.pi / 2 - _C1
_C3 = 6.123233995736766e-17
_SIN_TAYLOR = [(-1) ** k / math.factorial(2 * k + 1) for k in range(9)]  # r … r^17: next term < 1e-19 at π/4
_COS_TAYLOR = [(-1) ** k / math.factorial(2 * k) for k in range(10)]  # 1 … r^18


def _cos_sin(x):
    """``cos x``, ``sin x`` for 0 ≤ x < 1e8 by Cody–Waite reduction to |r| ≤ π/4 and Taylor
    polynomials (tests/test_special.py checks them through J0 and J1 against mpmath out to
    x = 1e4): cheaper on the CPU than XLA's own cos and sin, which the modulus–phase branch
    would need for every argument."""
    k = jnp.round(x * (2 / math.pi))
    r = ((x - k * _C1) - k * _C2) - k * _C3
    r2 = r * r
    sin_r = r * _horner(np.asarray(_SIN_TAYLOR), r2)
    cos_r = _horner(np.asarray(_COS_TAYLOR), r2)
    q = jnp.mod(k, 4.0)
    cos_x = jnp.where(q == 0, cos_r, jnp.where(q == 1, -sin_r, jnp.where(q == 2, -cos_r, sin_r)))
    sin_x = jnp.where(q == 0, sin_r, jnp.where(q == 1, cos_r, jnp.where(q == 2, -sin_r, -cos_r)))
    return cos_x, sin_x


@functools.partial(jax.jit, static_argnums=0)
def _bessel_j_compiled(n: int, x):
    # compiled as one program even when called eagerly: XLA fuses the Clenshaw recurrence (and
    # may contract its multiply–adds), so op-by-op evaluation would round differently from the
    # same expression inside a caller's jax.jit
    small_coef, p_coef, q_coef = _J_SERIES[n]
    large = jnp.abs(x) > _J_SWITCH
    near = _clenshaw(small_coef, jnp.where(large, 0.0, x), -_J_SWITCH, _J_SWITCH)
    ax = jnp.where(large, jnp.abs(x), 2 * _J_SWITCH)
    y = _J_SWITCH / ax
    p, q = _clenshaw(p_coef, y, 0.0, 1.0), _clenshaw(q_coef, y, 0.0, 1.0)
    # cos/sin of χ = x − π/4 (n = 0) or x − 3π/4 (n = 1) from cos x and sin x: forming χ would
    # round x − π/4 to ~x·1e-16, an error of that size in the phase for large x
    c, s = _cos_sin(ax)
    cos_chi, sin_chi = ((c + s), (s - c)) if n == 0 else ((s - c), -(s + c))
    far = jnp.sqrt(2.0 / (np.pi * ax)) * _SQRT_HALF * (p * cos_chi - q * sin_chi)
    return jnp.where(large, far * jnp.sign(x) ** n, near)  # J_n(−x) = (−1)^n J_n(x)


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
