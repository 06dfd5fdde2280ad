"""Benchmark of the isotropic evolution operator's paths (issue: core library).

Workload: the lobe of a Beckmann material (α0 = 0.1) evolved from μ0 to the coarsest scale
(s_to = δ) for a batch of 32 facet statistics (one per scale), producing the lobe on an
N × N grid of offsets. Measured in one run, in float64 on the CPU:

* grid path: ``evolve(..., method="grid", size=N).shape.on_grid()`` under ``jax.vmap``;
* floor: a raw batched ``rfft2`` + ``irfft2`` of the same grids (the least any grid method
  does to apply a spectral multiplier), timed alternately with the grid path and with the
  floor a second time (the control) in 41 rounds (order rotating). Times are the medians
  over rounds (the best round is recorded too, and every round's time); the control's
  ratio to the floor records how much either statistic moves by chance in the same run;
* in the same rounds, ``irfft2`` alone on a given spectrum and an elementwise product with a
  given multiplier followed by ``irfft2`` in one program: the least any grid method does once
  its multiplier is known (they separate the FFT's cost, that of a multiplier computed in
  the same program, and the grid path's own evaluation of the transform);
* SciPy baseline: sampling lobe and statistics on the grid and ``scipy.signal.fftconvolve``;
* accuracy of both against the exact answer (closed form or radial quadrature) on the grid;
* minor page faults per call of every candidate (median over the rounds): how often a call
  touches memory the allocator has just mapped afresh — a cost the timings include and that
  differs between programs with the allocator's state;
* which thread runs the inverse FFT in the grid path and in ``irfft2`` alone, how long it
  takes there and how many threads work on it (a ``jax.profiler`` trace of GGX at the
  largest N; see :func:`fft_threads`);
* closed form versus grid path *per query*: 1024 queries, each at its own scale (the grid
  path needs one grid per scale, the closed form one Gaussian).

The grid rows are measured twice: with XLA's default threads (two on this machine) and, in a
child process, with XLA on one thread (``grid_single_thread``), which measures the work
without the two-thread scheduling.

Run: ``python -m experiments.bench_evolve`` → experiments/results/bench_evolve.json.
"""

import argparse
import glob
import gzip
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path


SINGLE_THREAD_FLAGS = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
if "--single-thread" in sys.argv:  # must precede the first import of jax
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + SINGLE_THREAD_FLAGS).strip()

import jax  # noqa: E402


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.signal  # noqa: E402

import brdfscale as bs  # noqa: E402
from brdfscale import lobes, stats  # noqa: E402
from experiments._bench import best_time, interleaved_times, machine, median, write_json  # noqa: E402


BATCH = 32
ROUNDS = 41  # interleaved rounds of grid path, floor and control; the figures are medians
EXTENT = 0.8  # half-width of the slope grid shared by all methods (lobe α0 = 0.1, statistics ≤ 0.18)


def statistics(kind: str, width):
    if kind == "gaussian_mixture":  # skewed, zero-mean two-component mixture
        return stats.Mixture(
            jnp.array([0.7, 0.3]),
            [
                stats.Beckmann(width, mean=jnp.array([0.03, 0.0])),
                stats.Beckmann(1.5 * width, mean=jnp.array([-0.07, 0.0])),
            ],
        )
    return stats.GGX(width)


def _counting_page_faults(fn, counts: list):
    """``fn``, appending to ``counts`` the minor page faults of the process during each call
    (first touches of freshly mapped memory: the allocator handing out pages the kernel must
    map and zero; one ``getrusage`` on either side, about a microsecond)."""

    def counted():
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        fn()
        counts.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)

    return counted


LOBE = lobes.Beckmann(0.1)
WIDTHS = jnp.linspace(0.03, 0.12, BATCH)  # the statistics' widths, one per lobe of the batch


def grid_shape(kind: str, width, n: int):
    """The benchmarked lobe's shape: ``LOBE`` evolved to μ = ∞ by the grid path (N × N, half-width ``EXTENT``)."""
    return bs.evolve(LOBE, statistics(kind, width), stats.Delta(), method="grid", size=n, extent=EXTENT).shape


def bench_grid(kind: str, n: int) -> dict:
    grid_fn = jax.jit(jax.vmap(lambda w: grid_shape(kind, w, n).on_grid()[1]))
    grids = grid_fn(WIDTHS).block_until_ready()
    x = jnp.asarray(np.random.default_rng(0).random((BATCH, n, n)))
    floor_fn = jax.jit(lambda a: jnp.fft.irfft2(jnp.fft.rfft2(a), s=(n, n)))
    # the least a grid method does once its multiplier is known: one elementwise product with a
    # given spectrum and one irfft2, in one program (and the irfft2 alone)
    spectrum = jnp.fft.rfft2(x)
    multiplier = jnp.asarray(np.random.default_rng(1).random((n, n // 2 + 1)))
    multiply_fn = jax.jit(lambda X, M: jnp.fft.irfft2(X * M, s=(n, n)))
    irfft_fn = jax.jit(lambda X: jnp.fft.irfft2(X, s=(n, n)))
    # the control: the floor timed a second time in every round; its ratio to the floor shows
    # how far each statistic of the timings moves by chance alone
    candidates = {
        "grid": lambda: grid_fn(WIDTHS).block_until_ready(),
        "floor": lambda: floor_fn(x).block_until_ready(),
        "control": lambda: floor_fn(x).block_until_ready(),
        "multiply_irfft": lambda: multiply_fn(spectrum, multiplier).block_until_ready(),
        "irfft": lambda: irfft_fn(spectrum).block_until_ready(),
    }
    faults = {name: [] for name in candidates}
    times = interleaved_times(
        {name: _counting_page_faults(fn, faults[name]) for name, fn in candidates.items()}, repeat=ROUNDS
    )
    t_grid, t_floor = median(times["grid"]), median(times["floor"])

    # SciPy: sample g0 and s on the same grid and convolve (the straightforward implementation)
    u, _ = grid_shape(kind, WIDTHS[0], n).on_grid()
    h = float(u[1] - u[0])
    U = np.stack(np.meshgrid(np.asarray(u), np.asarray(u), indexing="xy"), -1)
    g0 = np.asarray(LOBE.density(jnp.asarray(U)))
    s_grids = np.stack([np.asarray(statistics(kind, w).density(jnp.asarray(U))) for w in WIDTHS])

    def scipy_all():
        return [scipy.signal.fftconvolve(g0, s, mode="same") * h * h for s in s_grids]

    t_scipy = best_time(scipy_all, repeat=7)
    # accuracy of both on the first lobe, against the auto path (closed form for the
    # mixture, radial Hankel quadrature for GGX) at the grid's nodes, relative to the peak
    reference = np.asarray(bs.evolve(LOBE, statistics(kind, WIDTHS[0]), stats.Delta()).density(jnp.asarray(U)))
    peak = np.max(reference)
    grid_error = float(np.max(np.abs(np.asarray(grids[0]) - reference)) / peak)
    scipy_error = float(np.max(np.abs(scipy_all()[0] - reference)) / peak)
    return {
        "statistics": kind,
        "grid_size": n,
        "batch": BATCH,
        "grid_path_s_per_lobe": t_grid / BATCH,
        "raw_fft_floor_s_per_grid": t_floor / BATCH,
        "scipy_fftconvolve_s_per_lobe": t_scipy / BATCH,
        "throughput_vs_floor": t_floor / t_grid,
        "throughput_vs_floor_best_of_rounds": times["floor"][0] / times["grid"][0],
        # throughput of the control (the floor again) relative to the floor, like throughput_vs_floor
        "control_throughput_vs_floor": {
            "median": median(times["floor"]) / median(times["control"]),
            "best_of_rounds": times["floor"][0] / times["control"][0],
        },
        "round_times_s": times,
        # the first entry of each list is the warm-up call's
        "minor_page_faults_per_call_median": {name: median(sorted(c[1:])) for name, c in faults.items()},
        "rounds": ROUNDS,
        "irfft2_alone_s_per_grid": median(times["irfft"]) / BATCH,
        "multiply_then_irfft2_s_per_grid": median(times["multiply_irfft"]) / BATCH,
        "speedup_vs_scipy": t_scipy / t_grid,
        "extent": EXTENT,
        "grid_path_max_error_rel_peak": grid_error,
        "scipy_max_error_rel_peak": scipy_error,
    }


def bench_queries(n: int) -> dict:
    """1024 queries (scale, offset) each at its own scale."""
    q = 1024
    rng = np.random.default_rng(1)
    alphas = jnp.asarray(rng.uniform(0.01, 0.09, q))
    offsets = jnp.asarray(rng.normal(scale=0.1, size=(q, 2)))

    def closed(a, u):
        return bs.evolve(LOBE, stats.Beckmann(0.1), stats.Beckmann(a)).density(u)

    def grid(a, u):
        return bs.evolve(LOBE, stats.Beckmann(0.1), stats.Beckmann(a), method="grid", size=n).density(u)

    closed_fn = jax.jit(jax.vmap(closed))
    grid_fn = jax.jit(jax.vmap(grid))
    t_closed = best_time(lambda: closed_fn(alphas, offsets).block_until_ready(), repeat=7)
    t_grid = best_time(lambda: grid_fn(alphas, offsets).block_until_ready(), repeat=3)
    err = float(
        jnp.max(jnp.abs(grid_fn(alphas, offsets) - closed_fn(alphas, offsets))) / jnp.max(closed_fn(alphas, offsets))
    )
    return {
        "queries": q,
        "grid_size": n,
        "closed_form_s_per_query": t_closed / q,
        "grid_path_s_per_query": t_grid / q,
        "closed_form_speedup_per_query": t_grid / t_closed,
        "grid_vs_closed_max_rel_error": err,
    }


def fft_records(events: list) -> dict:
    """The inverse FFTs of a ``jax.profiler`` trace (Chrome trace events), per thread pool
    they ran in (``tf_XLAEigen``: XLA's intra-op pool; ``tf_XLAPjRtCpuClient``: the thread
    that runs the program): how many, their median duration (ms), and the median time the
    *other* threads of the intra-op pool spent in pool tasks while each FFT ran, in units of
    its duration (``helpers``; the profiler's ``ThreadpoolListener::StartRegion`` …
    ``StopRegion`` on each pool thread): 0 when the FFT ran on its own, about 1 when another
    pool thread worked alongside it throughout."""
    threads = {e["tid"]: e["args"]["name"] for e in events if e.get("ph") == "M" and e.get("name") == "thread_name"}
    busy, open_since = {}, {}
    for e in sorted((e for e in events if e.get("ph") == "X"), key=lambda e: e["ts"]):
        if not threads.get(e["tid"], "").startswith("tf_XLAEigen"):
            continue
        if e["name"] == "ThreadpoolListener::StartRegion":
            open_since[e["tid"]] = e["ts"]
        elif e["name"] == "ThreadpoolListener::StopRegion" and e["tid"] in open_since:
            busy.setdefault(e["tid"], []).append((open_since.pop(e["tid"]), e["ts"]))
    by_pool = {}
    for e in events:
        if e.get("ph") == "X" and e["name"].startswith("fft") and e["dur"] > 0:
            start, stop = e["ts"], e["ts"] + e["dur"]
            helped = sum(
                max(0.0, min(stop, b) - max(start, a))
                for tid, spans in busy.items()
                if tid != e["tid"]
                for a, b in spans
            )
            pool = threads.get(e["tid"], "?").split("/")[0]
            by_pool.setdefault(pool, []).append((e["dur"] / 1e3, helped / e["dur"]))
    return {
        pool: {
            "ffts": len(d),
            "median_ms": median(sorted(t for t, _ in d)),
            "helpers_median": median(sorted(w for _, w in d)),
        }
        for pool, d in by_pool.items()
    }


def fft_threads(kind: str, n: int, calls: int = 21) -> dict:
    """Which thread runs the inverse FFT, for how long and with how much help from the pool
    (:func:`fft_records` of a ``jax.profiler`` trace): in the grid path (the spectrum's
    evaluation and the FFT in one XLA program), in ``irfft2`` alone on the same spectrum, and in
    the floor (``rfft2`` + ``irfft2``: two FFTs per call).

    XLA:CPU continues a program on whichever thread finished the operation it waited for:
    after a kernel split over the intra-op pool, often a pool thread. Its FFT (DUCC) splits
    its lines over the pool only when called from outside the pool — XLA's adapter
    (``ducc/google/threading.h``, ``adjust_nthreads``) gives a caller that is itself a pool
    thread one thread — so an FFT that lands on a pool thread runs on one thread. These figures
    show it as it happens (docs/benchmarks.md)."""

    def spectrum(w):
        shape = grid_shape(kind, w, n)
        h, _ = shape.grid_spacing()
        return shape.cf_grid(shape.frequency_grid(h))

    grid_fn = jax.jit(jax.vmap(lambda w: grid_shape(kind, w, n).on_grid()[1]))
    given = jax.jit(jax.vmap(spectrum))(WIDTHS)
    irfft_fn = jax.jit(lambda X: jnp.fft.irfft2(X, s=(n, n)))
    x = jnp.fft.irfft2(given, s=(n, n))
    floor_fn = jax.jit(lambda a: jnp.fft.irfft2(jnp.fft.rfft2(a), s=(n, n)))
    out = {"statistics": kind, "grid_size": n, "calls": calls}
    for name, fn in (
        ("grid_path", lambda: grid_fn(WIDTHS).block_until_ready()),
        ("irfft2_alone", lambda: irfft_fn(given).block_until_ready()),
        ("floor", lambda: floor_fn(x).block_until_ready()),
    ):
        fn()
        with tempfile.TemporaryDirectory() as tmp:
            with jax.profiler.trace(tmp):
                for _ in range(calls):
                    fn()
            traces = glob.glob(os.path.join(tmp, "**", "*.trace.json.gz"), recursive=True)
            if not traces:
                return {**out, "error": "no profiler trace written"}
            out[name] = fft_records(json.load(gzip.open(traces[0]))["traceEvents"])
    return out


def grid_rows(sizes) -> list:
    return [bench_grid(kind, n) for kind in ("gaussian_mixture", "ggx") for n in sizes]


def single_thread_rows(sizes) -> list:
    """The grid rows again in a child process whose XLA runs on one thread (``XLA_FLAGS`` must
    be set before jax starts): the work itself, free of the two-thread scheduling noise."""
    with tempfile.TemporaryDirectory() as tmp:
        rows = Path(tmp) / "rows.json"
        cmd = [
            sys.executable,
            "-m",
            "experiments.bench_evolve",
            "--single-thread",
            "--rows",
            str(rows),
            "--sizes",
            *map(str, sizes),
        ]
        subprocess.run(cmd, check=True, cwd=Path(__file__).resolve().parents[1])  # the checkout: experiments/'s parent
        return json.loads(rows.read_text())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--quick", action="store_true", help="small sizes, for the smoke test")
    parser.add_argument(
        "--single-thread",
        action="store_true",
        help="(internal) time the grid rows with XLA on one thread and write them to --rows",
    )
    parser.add_argument("--rows", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    sizes = [64] if args.quick else args.sizes
    if args.single_thread:
        args.rows.write_text(json.dumps(grid_rows(sizes)))
        return None
    results = {
        "benchmark": "bench_evolve",
        "machine": machine(),
        "load_average_at_start": os.getloadavg(),
        "dtype": "float64",
        "grid": grid_rows(sizes),
        "grid_single_thread": single_thread_rows(sizes),
        "queries": bench_queries(sizes[-1] if not args.quick else 64),
        "fft_threads": fft_threads("ggx", sizes[-1]),
    }
    name = "bench_evolve_quick" if args.quick else "bench_evolve"
    path = write_json(name, results)
    for threads, row in [("default", r) for r in results["grid"]] + [
        ("1 thread", r) for r in results["grid_single_thread"]
    ]:
        print(
            f"{threads:>8} {row['statistics']:>17} N={row['grid_size']:4d}: "
            f"grid {row['grid_path_s_per_lobe'] * 1e3:8.3f} ms/lobe, "
            f"floor {row['raw_fft_floor_s_per_grid'] * 1e3:8.3f} ms, scipy "
            f"{row['scipy_fftconvolve_s_per_lobe'] * 1e3:8.3f} ms; "
            f"throughput/floor {row['throughput_vs_floor']:.2f}, speedup vs scipy {row['speedup_vs_scipy']:.1f}"
        )
    qr = results["queries"]
    print(
        f"queries: closed form {qr['closed_form_s_per_query'] * 1e9:.1f} ns/query, "
        f"grid {qr['grid_path_s_per_query'] * 1e6:.1f} µs/query, "
        f"ratio {qr['closed_form_speedup_per_query']:.0f}"
    )
    print(f"wrote {path}")
    return results


if __name__ == "__main__":
    main()
