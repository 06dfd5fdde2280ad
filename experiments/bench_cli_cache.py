"""Benchmark of the command's persistent compilation cache: ``brdfscale fit``, run after run.

The demo's measurement set is made once (``brdfscale demo``: the built-in Gaussian random
surface at five scales) and fitted by ``brdfscale fit`` with the demo's options (Gaussian-
surface law, 4 starts, 16 walkers × 1000 emcee steps) in fresh processes: first with an
empty cache (the first run after installing), then ``ROUNDS`` times alternately with the
cache warm and with ``--no-compilation-cache``. Figures: wall time of the whole command
(interpreter start, imports, reading, fitting, sampling, report) — the cold run, the median
of each alternating series, and the saving on every run after the first; the cache's size
on disk and its number of entries.

Writes experiments/results/bench_cli_cache.json.
Run: ``flock /tmp/brdfscale-bench.lock python -m experiments.bench_cli_cache``.
"""

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from experiments._bench import machine, median, write_json


ROUNDS = 3
FIT_OPTIONS = [
    "--law",
    "gaussian_surface",
    "--starts",
    "4",
    "--steps",
    "1000",
    "--walkers",
    "16",
    "--no-progress",
    "--force",
]


def _command(*args, cache: Path) -> float:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE"))}
    env["BRDFSCALE_COMPILATION_CACHE"] = str(cache)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "brdfscale", *args], check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main():
    load_at_start = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cache = tmp / "cache"
        _command(
            "--no-compilation-cache", "demo", "--out", str(tmp / "demo"), "--steps", "0", "--no-progress", cache=cache
        )
        measurements = tmp / "demo" / "measurements.exr"

        def fit(*flags):
            return _command(*flags, "fit", str(measurements), "--out", str(tmp / "fit"), *FIT_OPTIONS, cache=cache)

        cold = fit()
        warm, off = [], []
        for _ in range(ROUNDS):
            warm.append(fit())
            off.append(fit("--no-compilation-cache"))
        files = [p for p in cache.rglob("*") if p.is_file()]
        results = {
            "benchmark": "bench_cli_cache",
            "machine": machine(),
            "load_average_at_start": load_at_start,
            "command": ["brdfscale", "fit", "measurements.exr", "--out", "DIR", *FIT_OPTIONS],
            "rounds": ROUNDS,
            "cold_cache_s": cold,
            "warm_cache_s": sorted(warm),
            "no_cache_s": sorted(off),
            "warm_cache_median_s": median(sorted(warm)),
            "no_cache_median_s": median(sorted(off)),
            "saving_per_run_s": median(sorted(off)) - median(sorted(warm)),
            "cache_entries": sum(not p.name.endswith("-atime") for p in files),
            "cache_bytes": sum(p.stat().st_size for p in files),
        }
    path = write_json("bench_cli_cache", results)
    print(
        f"cold cache {cold:.1f} s; warm cache median {results['warm_cache_median_s']:.1f} s; no cache median "
        f"{results['no_cache_median_s']:.1f} s; {results['cache_entries']} entries, "
        f"{results['cache_bytes'] / 2**20:.1f} MiB"
    )
    print("wrote", path)
    return results


if __name__ == "__main__":
    main()
