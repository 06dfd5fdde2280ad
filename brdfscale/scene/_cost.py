"""The planner's cost model: predicted work in relative *cost units*, not seconds.

Work is counted in two kinds and weighted into one number:

* *evaluations*: transcendental function calls (a statistic's transform, J₀, e^{ix}, a
  lobe sample), each worth ``EVALUATION_UNITS`` units;
* *multiply-adds*: the dense algebra (table products, FFT butterflies, interpolation), one
  unit each.

The unit is deliberately not a second: the planner only compares predictions with each other
(closed form against radial against grid, direct sums against tables), so a common scale
error does not change its choices, and the conversion to seconds depends on the machine, its
load and the JAX backend. experiments/bench_planner.py measures it — the seconds per unit of
every plan it times, and whether the predicted ranking of the paths forced on one problem
matches their measured ranking — instead of assuming it.
"""

import math


EVALUATION_UNITS = 20.0
CALL_UNITS = 5e4
"""The fixed cost of one call of a jit-compiled plan (dispatch, argument flattening)."""


def units(evaluations: float, multiply_adds: float) -> float:
    """Predicted cost of ``evaluations`` transcendental calls and ``multiply_adds`` in units."""
    return evaluations * EVALUATION_UNITS + multiply_adds


def fft2_multiply_adds(n: int) -> float:
    """A real n×n forward-or-inverse FFT: about 2.5 n² log₂ n²."""
    return 2.5 * n * n * math.log2(max(n * n, 2))


def fft_multiply_adds(points: float) -> float:
    """A complex FFT over ``points`` samples (any dimension): about 5 N log₂ N."""
    return 5.0 * points * math.log2(max(points, 2))
