"""The planner's cost model: work counted in two units and converted to predicted seconds.

* *evaluations*: transcendental function calls (a statistic's transform, J₀, e^{ix});
* *multiply-adds*: the dense algebra (table products, FFT butterflies, interpolation).

The per-unit times are rough figures for one core of a 2-core x86 CPU running JAX in float64
(FIELD-NOTES: a 256² rfft2+irfft2 takes ~1.9 ms); experiments/bench_planner.py records the
predicted next to the measured time of every plan, so the model's accuracy is measured, not
assumed. The planner only compares predictions with each other, so a common scale error
does not change its choices.
"""

import math

SECONDS_PER_EVALUATION = 2e-8
SECONDS_PER_MULTIPLY_ADD = 1e-9


def seconds(evaluations: float, multiply_adds: float) -> float:
    return evaluations * SECONDS_PER_EVALUATION + multiply_adds * SECONDS_PER_MULTIPLY_ADD


def fft2_multiply_adds(n: int) -> float:
    """A real n×n forward-or-inverse FFT: about 2.5 n² log₂ n²."""
    return 2.5 * n * n * math.log2(max(n * n, 2))
