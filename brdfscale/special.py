"""Bessel functions for real arguments in pure JAX, differentiable, accurate to float64 rounding.

* :func:`j0`, :func:`j1` — ``J0``, ``J1`` (the Hankel transforms of isotropic statistics);
* :func:`jinc` — ``2 J1(x)/x`` with its limit 1 at 0;
* :func:`k0`, :func:`xk1` — ``K0`` and ``x K1(x)`` (the Matérn / GGX transforms).

How each is evaluated and its error bound: the docstring of :mod:`brdfscale._special`;
accuracy against SciPy and mpmath is tested in tests/test_special.py.
"""

from ._special import j0, j1, jinc, k0, xk1


__all__ = ["j0", "j1", "jinc", "k0", "xk1"]
