"""The transforms ``H_n(W)`` of the regularised plus-distributions (seed §6, docs/conventions.md §4).

With ``z = |W| x0`` and ``t = x/x0``,

    H_n(W) = ∫_0^{x0} (logⁿ(x/x0)/x) (J₀(W x) − 1) dx = ∫_0^1 (logⁿt / t) (J₀(z t) − 1) dt,

an entire function of ``z²``, of sign ``(−1)^{n+1}`` for ``z > 0`` (``logⁿt`` has sign ``(−1)ⁿ``
and ``J₀ ≤ 1``), so relative accuracy is well defined everywhere. Two evaluations:

* ``z ≤ 8``: the power series (docs/conventions.md §4)

      H_n = (−1)ⁿ n! Σ_{k≥1} (−z²/4)^k / ((k!)² (2k)^{n+1}),

  alternating; at ``z = 8`` the sum of moduli exceeds the value by at most 35 (n = 0), so the
  rounding error stays below 4e-15 relative. 32 terms truncate below 1e-28.

* ``z > 8``: the exact split ``H_n(z) = P_n(ℓ) − T_n(z)``, ``ℓ = ln(z e^{γ_E}/2)``.

  *Polynomial.* For ``0 < s < 3/2``, ``F(s) = ∫_0^1 t^{s−1}(J₀(zt) − 1) dt`` equals
  ``z^{−s} M(s) − 1/s − ∫_1^∞ t^{s−1} J₀(zt) dt`` with the Mellin transform
  ``M(s) = ∫_0^∞ u^{s−1}J₀(u) du = 2^{s−1}Γ(s/2)/Γ(1 − s/2)``, and ``H_n = ∂ₛⁿF(0)``. Since
  ``ln Γ(1+x) − ln Γ(1−x) = −2γ_E x − 2 Σ_{k odd ≥ 3} ζ(k) x^k/k``,

      z^{−s}M(s) − 1/s = (exp(−sℓ + E(s)) − 1)/s,   E(s) = −Σ_{k odd ≥ 3} ζ(k) s^k / (k 2^{k−1}),

  so ``P_n(ℓ) = n! [s^{n+1}] exp(−sℓ + E(s)) = n! Σ_j e_j (−ℓ)^{n+1−j}/(n+1−j)!`` with
  ``exp(E(s)) = Σ_j e_j s^j`` (``e_0 = 1, e_1 = e_2 = 0, e_3 = −ζ(3)/12``, …). The leading term
  is ``(−ℓ)^{n+1}/(n+1)``; ``P_0 = −ℓ``.

  *Decaying terms.* ``T_n(z) = ∫_1^∞ (logⁿt / t) J₀(z t) dt = O(n! z^{−3/2−n})``. With
  ``J₀ = Re H₀⁽¹⁾``, the path rotated to ``t = 1 + i y`` (where ``H₀⁽¹⁾(z t)`` decays like
  ``e^{−z y}``) and Hankel's Laplace-type representation (Watson, *Bessel Functions*, §7.2)
  ``H₀⁽¹⁾(ζ) = √(2/(πζ)) e^{i(ζ − π/4)} π^{−1/2} ∫_0^∞ e^{−u} u^{−1/2} (1 + iu/(2ζ))^{−1/2} du``,

      T_n(z) = √2/(π z^{3/2}) Re[ i e^{i(z−π/4)} ∫∫ e^{−x} e^{−u} u^{−1/2}
               logⁿ(1 + ix/z) (1 + ix/z)^{−3/2} (1 + iu/(2z + 2ix))^{−1/2} dx du ],

  an exact, convergent form of the Hankel-type asymptotic series (whose optimal truncation
  would only reach ``e^{−z}``). Gauss–Laguerre rules (24 nodes in x, 24 generalised nodes with
  α = −1/2 in u) integrate it: the integrand's nearest singularities lie a distance ≥ z ≥ 8
  from the positive axes, and the rule's error at z = 8 is below 1e-16 relative to ``H_n``.

Both branches are evaluated on safe dummy arguments where they do not apply and the series
is written in ``z²``, so values and gradients are finite at ``W = 0`` and at the switch, under
``jax.jit`` and ``jax.grad``, in float32 and float64. Accuracy against mpmath is tested in
tests/test_plus_transform.py and tabulated by experiments/plus_transform_accuracy.py.
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InvalidInputError
from .._validation import as_float_array


MAX_ORDER = 6
"""The highest order ``n`` of ``[logⁿ(|m|/x0)/|m|²]₊`` supported."""

SWITCH = 8.0
"""``z = |W| x0`` above which the polynomial-plus-decaying-terms form replaces the series."""

_N_SERIES = 32
_N_LAGUERRE = 24
_EULER_GAMMA = 0.57721566490153286061
# ζ(3), ζ(5), ζ(7): all that P_n needs for n ≤ 6 (powers up to s⁷).
_ZETA_ODD = {3: 1.2020569031595942854, 5: 1.0369277551433699263, 7: 1.0083492773819228268}


def _series_coefficients(n: int) -> np.ndarray:
    """c_k with H_n = Σ_{k=1..K} c_k q^k, q = z²/4: c_k = (−1)^{n+k} n! / ((k!)² (2k)^{n+1})."""
    k = np.arange(1, _N_SERIES + 1)
    log_fact = np.array([math.lgamma(j + 1.0) for j in k])
    magnitude = np.exp(math.lgamma(n + 1.0) - 2 * log_fact - (n + 1) * np.log(2.0 * k))
    return (-1.0) ** (n + k) * magnitude


def _exp_e_coefficients(count: int) -> np.ndarray:
    """Taylor coefficients e_j of exp(E(s)), E(s) = −Σ_{k odd ≥ 3} ζ(k) s^k/(k 2^{k−1})."""
    E = np.zeros(count)
    for k, zeta in _ZETA_ODD.items():
        if k < count:
            E[k] = -zeta / (k * 2.0 ** (k - 1))
    e = np.zeros(count)
    e[0] = 1.0
    for j in range(1, count):  # (exp E)' = E' exp E  ⇒  j e_j = Σ_m m E_m e_{j−m}
        e[j] = sum(m * E[m] * e[j - m] for m in range(1, j + 1)) / j
    return e


def _polynomial_coefficients(n: int) -> np.ndarray:
    """a_p with P_n(ℓ) = Σ_p a_p ℓ^p: a_p = n! e_{n+1−p} (−1)^p / p!."""
    e = _exp_e_coefficients(n + 2)
    p = np.arange(n + 2)
    return np.array([math.factorial(n) * e[n + 1 - q] * (-1.0) ** q / math.factorial(q) for q in p])


def _gauss_laguerre(count: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights for ∫_0^∞ x^α e^{−x} f(x) dx (Golub–Welsch)."""
    k = np.arange(1, count)
    jacobi = (
        np.diag(2 * np.arange(count) + 1 + alpha)
        + np.diag(np.sqrt(k * (k + alpha)), 1)
        + np.diag(np.sqrt(k * (k + alpha)), -1)
    )
    nodes, vectors = np.linalg.eigh(jacobi)
    return nodes, vectors[0] ** 2 * math.gamma(1 + alpha)


_SERIES = np.stack([_series_coefficients(n) for n in range(MAX_ORDER + 1)])  # (7, K)
_POLYNOMIAL = [_polynomial_coefficients(n) for n in range(MAX_ORDER + 1)]
_X, _WX = _gauss_laguerre(_N_LAGUERRE, 0.0)
_U, _WU = _gauss_laguerre(_N_LAGUERRE, -0.5)


def _series(q, max_order: int):
    """Σ_k c_k q^k for n = 0..max_order by Horner's rule; shape (..., max_order+1)."""
    coefficients = jnp.asarray(_SERIES[: max_order + 1], dtype=q.dtype)  # (n, K)
    total = jnp.zeros(q.shape + (max_order + 1,), dtype=q.dtype)
    for k in range(_N_SERIES - 1, -1, -1):
        total = (total + coefficients[:, k]) * q[..., None]
    return total


def _polynomial(ell, max_order: int):
    out = []
    for n in range(max_order + 1):
        value = jnp.zeros_like(ell)
        for a in _POLYNOMIAL[n][::-1]:
            value = value * ell + float(a)
        out.append(value)
    return jnp.stack(out, axis=-1)


def _decaying(z, max_order: int):
    """T_n(z) for n = 0..max_order (z > 0, intended for z ≥ SWITCH); shape (..., max_order+1)."""
    dtype = z.dtype
    cdtype = jnp.result_type(dtype, jnp.complex64)
    x = jnp.asarray(_X, dtype)
    u = jnp.asarray(_U, dtype)
    weights = jnp.asarray(np.outer(_WX, _WU), dtype)  # (x, u)
    zz = z[..., None, None]
    t = 1 + 1j * x[:, None] / zz  # (..., x, 1)
    root = jnp.sqrt((2 * zz + 2j * x[:, None]) / (2 * zz + 2j * x[:, None] + 1j * u[None, :]))
    base = (weights * t**-1.5 * root).astype(cdtype)  # (..., x, u)
    log_t = jnp.log(t).astype(cdtype)
    integrals = []
    power = jnp.ones_like(log_t)
    for _ in range(max_order + 1):
        integrals.append(jnp.sum(power * base, axis=(-2, -1)))
        power = power * log_t
    integral = jnp.stack(integrals, axis=-1)  # (..., n)
    theta = (z - math.pi / 4)[..., None]
    value = -jnp.sin(theta) * jnp.real(integral) - jnp.cos(theta) * jnp.imag(integral)
    return (math.sqrt(2.0) / math.pi) * value / (z**1.5)[..., None]


Z_DECAYING = 1e15
"""Above this ``z`` the decaying terms ``T_n`` (``O(n! z^{−3/2−n})``, below 1e-20 of ``|H_n|``) are
dropped: ``H_n = P_n(ℓ)``, which needs only ``ln z`` and so stays finite where ``z²`` overflows."""


@functools.partial(jax.jit, static_argnames="max_order")
def transforms_from_square(z2, max_order: int, log_z=None):
    """``H_0 … H_{max_order}`` at ``z = √z2`` (z2 = |W|² x0² ≥ 0); shape (..., max_order+1).

    Working from ``z²`` keeps the gradient finite at ``W = 0``. ``log_z``: ``ln z`` where
    ``z2 > SWITCH²`` (any finite value elsewhere), for callers whose ``z²`` may overflow to
    inf (:func:`transforms_scaled`); default ``ln √z2``. ``z2 = inf`` with a finite ``log_z`` is
    a valid input (the polynomial branch needs only ``ln z``).
    """
    large = z2 > SWITCH**2
    q = jnp.where(large, 0.0, z2) / 4
    z = jnp.sqrt(jnp.where(large, z2, 4 * SWITCH**2))
    log_z = jnp.log(z) if log_z is None else jnp.where(large, log_z, math.log(2 * SWITCH))
    ell = log_z + (_EULER_GAMMA - math.log(2.0))
    far = z > Z_DECAYING
    decaying = jnp.where(far[..., None], 0.0, _decaying(jnp.where(far, Z_DECAYING, z), max_order))
    expansion = _polynomial(ell, max_order) - decaying
    return jnp.where(large[..., None], expansion, _series(q, max_order))


def transforms_scaled(W, x0, max_order: int):
    """``H_0 … H_{max_order}`` at ``z = |W| x0`` for frequencies ``W`` (..., 2) and ``x0 > 0``.

    ``z`` is formed as ``|W x0|`` — the product first, then the norm — so a finite ``z`` is found
    wherever it is representable, however large ``|W|`` or ``x0`` is alone (``|W|²`` overflows
    above 1.3e154 and ``x0²`` likewise, e.g. ``W = 1e200, x0 = 1e-200`` is ``z = 1``; forming
    ``|W|² x0²`` gave NaN there); where ``z²`` itself overflows, only
    ``ln z = ln s + ½ ln Σ(W_i/s)² + ln x0`` (``s = max |W_i|``) enters. The square
    ``Σ (W_i x0)²`` keeps gradients finite at ``W = 0``."""
    W = jnp.asarray(W)
    return _transforms_of(W * x0, W, x0, max_order)


def transforms_radial(k, x0, max_order: int):
    """``H_0 … H_{max_order}`` at ``z = k x0`` for radial frequencies ``k ≥ 0`` (as
    :func:`transforms_scaled`)."""
    k = jnp.asarray(k)
    return _transforms_of((k * x0)[..., None], k[..., None], x0, max_order)


def _transforms_of(V, W, x0, max_order: int):
    """From the scaled frequencies ``V = W x0`` (..., d) and the factors ``W``, ``x0`` (for
    ``ln z`` where ``z² = |V|²`` overflows, or ``V`` itself does)."""
    z2 = jnp.sum(V * V, axis=-1)
    large = z2 > SWITCH**2
    s = jnp.max(jnp.abs(W), axis=-1)
    s_safe = jnp.where(large & (s > 0), s, 1.0)
    ratio = jnp.where(large[..., None], W, 1.0) / s_safe[..., None]
    log_z = jnp.log(s_safe) + 0.5 * jnp.log(jnp.sum(ratio * ratio, axis=-1)) + jnp.log(x0)
    return transforms_from_square(z2, max_order, log_z)


def check_order(order) -> int:
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or not 0 <= order <= MAX_ORDER:
        raise InvalidInputError(f"order must be an integer n with 0 ≤ n ≤ {MAX_ORDER}; got {order!r}.")
    return int(order)


def plus_transform(z: Float[ArrayLike, "*batch"], order: int) -> Float[Array, "*batch"]:
    """``H_n`` at ``z = |W| x0`` (dimensionless, ≥ 0): the transform of ``h_n`` (docs/conventions.md §4).

    ``H_n(W) = ∫_0^{x0} (logⁿ(x/x0)/x)(J₀(Wx) − 1) dx``, ``n = order ∈ {0, …, 6}``; see the
    module docstring for the two evaluations and their accuracy (≤ 3e-14 relative in float64
    over ``z ∈ [1e-6, 1e8]``, measured by experiments/plus_transform_accuracy.py). Finite for
    every finite z (above ``Z_DECAYING`` only ``ln z`` enters).
    """
    order = check_order(order)
    z = as_float_array(z, "z")
    z2 = z * z
    log_z = jnp.log(jnp.where(z2 > SWITCH**2, jnp.abs(z), 1.0))  # finite where z² overflows (|z| > 1.3e154)
    return transforms_from_square(z2, order, log_z)[..., order]
