"""mpmath references for the plus-distribution transforms H_n (shared by tests and experiments).

* ``series(n, z)``: the defining power series summed with enough digits to absorb its
  cancellation (about z/2.3 extra digits), for z up to a few thousand.
* ``polynomial(n, z)``: ``n! [s^{n+1}] (2/z)^s Γ(1+s/2)/Γ(1−s/2)`` by mpmath's Taylor
  expansion of the Gamma functions (independent of the ζ-series used by the library).
* ``decaying(n, z)``: ``∫_1^∞ (logⁿt/t) J₀(zt) dt`` by mpmath quadrature along ``t = 1 + i x/z``
  with mpmath's Hankel function ``H₀⁽¹⁾`` (slow: seconds per value).
"""

import mpmath as mp


def series(n: int, z) -> mp.mpf:
    z = mp.mpf(z)
    with mp.workdps(int(30 + z / 2.3)):
        q = -((z / 2) ** 2)
        term, total, k = mp.mpf(1), mp.mpf(0), 0
        while True:
            k += 1
            term *= q / (k * k)
            t = term / (2 * k) ** (n + 1)
            total += t
            if k > z and abs(t) <= mp.mpf(10) ** -35 * abs(total):
                break
        value = (-1) ** n * mp.factorial(n) * total
    return +value


def polynomial(n: int, z) -> mp.mpf:
    z = mp.mpf(z)
    coefficients = mp.taylor(lambda s: (2 / z) ** s * mp.gamma(1 + s / 2) / mp.gamma(1 - s / 2), 0, n + 1)
    return coefficients[n + 1] * mp.factorial(n)


def decaying(n: int, z) -> mp.mpf:
    z = mp.mpf(z)

    def integrand(x):
        t = 1 + 1j * x / z
        return mp.re(1j * mp.log(t) ** n / t * mp.hankel1(0, z * t)) / z

    return mp.quad(integrand, [0, 2, 8, 20, 50])


def reference(n: int, z) -> float:
    """H_n(z) to well below float64 rounding."""
    with mp.workdps(30):
        if z <= 3000:
            return float(series(n, z))
        return float(polynomial(n, z) - decaying(n, z))
