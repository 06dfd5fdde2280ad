"""Argument checks for code built on brdfscale (its :mod:`fitting` package uses them).

Each returns the checked value in its canonical Python type or raises
:class:`brdfscale.InvalidInputError` naming the argument, what it got and what is accepted:

* :func:`integer` — an int ≥ a minimum (Python or NumPy integers; not bool, not float);
* :func:`real` — a finite real scalar ≥ (or >) a minimum;
* :func:`flag` — a bool (Python or NumPy);
* :func:`require_float64` — refuses unless JAX computes in float64, naming the line to add.

Tested in tests/test_robustness.py and through every constructor that uses them.
"""

from ._validation import flag, integer, real, require_float64


__all__ = ["integer", "real", "flag", "require_float64"]
