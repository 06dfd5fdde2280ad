"""Benchmark: size, time and peak memory of a 4096² synthesis, facet statistics, a synthetic
measurement and its OpenEXR file.

Run:  python -m experiments.bench_synth [--size 4096] [--out experiments/results/bench_synth.json]

Baseline measured in the same run: the FFT floor of the synthesis (one rfft2 + irfft2 of
an N² float64 array, which any spectral synthesis must pay); and the cost of histogramming
N²/4 slope samples in chunks with ``stats.SlopeHistogram`` (cloud in cell). Peak memory:
``tracemalloc`` (NumPy allocations of each stage) and the process's maximum resident set size
(everything, JAX included).
"""

import argparse
import json
import os
import platform
import resource
import tempfile
import time
import tracemalloc
from importlib.metadata import version
from pathlib import Path

import jax
import numpy as np

from brdfscale import exr, stats, synth
from brdfscale.files import atomic_write
from brdfscale.stats import SlopeHistogram, Tabulated


def _stage(fn, *args, **kw):
    tracemalloc.start()
    t0 = time.perf_counter()
    result = fn(*args, **kw)
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return result, {"seconds": round(seconds, 3), "numpy_peak_MiB": round(peak / 2**20, 1)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=4096)
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "bench_synth.json"))
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)
    n = args.size
    spectrum = stats.GaussianCorrelation(0.05, 8.0)
    scales = [4.0, 16.0, 64.0]
    incident = [[0.0, 0.0, 1.0], [0.5, 0.0, np.sqrt(0.75)]]

    # warm-up at a small size so that JAX compilation is not timed
    small = synth.spectral_field(spectrum, size=256, seed=0)
    synth.facet_statistics(small, scales)
    synth.gonioreflectometer(small, scales, incident, extent=0.04, pixels=65, noise=synth.PoissonNoise(1e4), seed=1)

    record = {
        "size": n,
        "spectrum": "GaussianCorrelation(rms_height=0.05, correlation_length=8 px)",
        "scales_px": scales,
    }
    field, record["spectral_field"] = _stage(synth.spectral_field, spectrum, size=n, seed=0)
    record["height_field_MiB"] = round(field.heights.nbytes / 2**20, 1)
    _, record["facet_slopes_3_scales"] = _stage(lambda: [synth.facet_slopes(field, mu) for mu in scales])
    stats_result, record["facet_statistics_3_scales"] = _stage(synth.facet_statistics, field, scales)
    record["facet_slope_variance_x"] = {str(s.mu): float(s.covariance[0, 0]) for s in stats_result}
    law = stats.GaussianSurface(spectrum, window="box", n_k=256)
    record["analytic_variance_x"] = {str(mu): float(law.slope_covariance(mu)[0, 0]) for mu in scales}
    _, record["global_slopes"] = _stage(synth.global_slopes, field)
    mset, record["gonioreflectometer_3_scales_2_incident_poisson"] = _stage(
        synth.gonioreflectometer, field, scales, incident, extent=0.04, pixels=65, noise=synth.PoissonNoise(1e4), seed=1
    )
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "set.exr")
        _, record["write_measurements"] = _stage(exr.write_measurements, path, mset)
        record["exr_file_bytes"] = os.path.getsize(path)
        _, record["read_measurements"] = _stage(exr.read_measurements, path)

    # baselines
    noise = np.random.default_rng(0).standard_normal((n, n))
    _, record["baseline_fft_floor_rfft2_irfft2"] = _stage(lambda: np.fft.irfft2(np.fft.rfft2(noise), s=(n, n)))
    samples = np.random.default_rng(1).standard_normal((n * n // 4, 2)) * 0.01

    def streaming():
        hist = SlopeHistogram(0.06, 129)
        for chunk in np.array_split(samples, 8):
            hist.add(chunk[:, 0], chunk[:, 1])
        return Tabulated.from_histogram(hist)

    _, record["slope_histogram_N2_over_4"] = _stage(streaming)
    record["max_rss_MiB"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    record["machine"] = {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "processor": platform.processor(),
    }
    record["versions"] = {p: version(p) for p in ("numpy", "jax", "jaxlib", "equinox", "OpenEXR")}
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    text = json.dumps(record, indent=2)
    atomic_write(args.out, lambda tmp: Path(tmp).write_text(text), overwrite=True)
    print(json.dumps(record, indent=2))


if __name__ == "__main__":
    main()
