"""Cost of evaluating an evolved lobe against the number of offsets Q (issue "One evaluation contract").

For the closed-form, radial (README's lobe), grid (anisotropic lobe, mixture statistics with a
shifted disk) and tabulated cases, in
float64 and float32, and Q = 10²…10⁷ offsets on a square image: the wall time of
``lobe.density(u)`` (first call, which compiles, and warm: best of three), the process's peak
RSS (a fresh subprocess per point, so that the high-water mark is this point's alone; the RSS
before the evaluation is recorded beside it) and the error against the evaluation of the same
lobe at 64 sampled offsets, each on its own (a single query is evaluated at itself), relative to the
lobe's peak. With ``--baseline-rev REV`` the same points at Q = 10² and 10³ run on brdfscale as
of git revision REV (exported to a temporary directory), in the same run.

Run: ``python -m experiments.bench_queries --baseline-rev e0f374b`` →
experiments/results/bench_queries.json (``--quick``: fewer points, bench_queries_quick.json).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]  # the checkout (experiments/'s parent)
CASES = ("closed_form", "radial", "grid", "tabulated")
TOL = {"closed_form": 1e-10, "radial": 1e-10, "grid": 1e-8, "tabulated": 1e-8}
TOL32 = 1e-5


def _make(case: str, dtype):
    import jax.numpy as jnp
    import numpy as np

    import brdfscale as bs
    from brdfscale import lobes, stats

    f = lambda x: jnp.asarray(x, dtype)
    tol = TOL[case] if dtype == jnp.float64 else max(TOL[case], TOL32)
    if case == "closed_form":
        return bs.evolve(lobes.Beckmann(f(0.08)), stats.Beckmann(f(0.1)), stats.Beckmann(f(0.05)), tol=tol)
    if case == "radial":  # README's example
        law = stats.ScaledFamily(stats.GGX, stats.WidthLaw(alpha_max=f(0.15), mu_c=f(1.0), exponent=f(0.8)))
        return bs.evolve(lobes.Beckmann(f(0.08)), law.at(f(1.0)), law.at(f(10.0)), tol=tol)
    if case == "grid":  # anisotropic Beckmann lobe, mixture statistics with a shifted disk
        lobe = lobes.Beckmann(alpha_x=f(0.06), alpha_y=f(0.1))
        s_from = stats.Mixture(f([0.7, 0.3]), [stats.Beckmann(f(0.08)), stats.Disk(f(0.05), mean=f([0.03, -0.02]))])
        return bs.evolve(lobe, s_from, stats.Delta(), tol=tol)
    # tabulated: a measured-like lobe (samples on a 65² grid) blurred by anisotropic Beckmann statistics
    x = np.linspace(-0.3, 0.3, 65)
    X, Y = np.meshgrid(x, x)
    values = np.exp(-(X**2 / 0.006 + Y**2 / 0.01))
    return bs.evolve(
        lobes.Tabulated(f(values), extent=0.3), stats.Beckmann(alpha_x=f(0.05), alpha_y=f(0.08)), stats.Delta(), tol=tol
    )


def _offsets(q: int, dtype):
    import jax.numpy as jnp

    side = int(round(q**0.5))
    x = jnp.linspace(-0.4, 0.4, side, dtype=dtype)
    u = jnp.stack(jnp.meshgrid(x, x), -1).reshape(-1, 2)
    if u.shape[0] < q:  # pad to exactly q offsets
        u = jnp.concatenate([u, u[: q - u.shape[0]]])
    return u[:q]


def point(case: str, dtype_name: str, q: int) -> dict:
    """One measurement, in this (fresh) process."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    dtype = jnp.float64 if dtype_name == "float64" else jnp.float32
    t0 = time.perf_counter()
    lobe = _make(case, dtype)
    evolve_s = time.perf_counter() - t0
    u = _offsets(q, dtype)
    u.block_until_ready()
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    t0 = time.perf_counter()
    values = lobe.density(u).block_until_ready()
    first = time.perf_counter() - t0
    warm = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        lobe.density(u).block_until_ready()
        warm = min(warm, time.perf_counter() - t0)
    rss_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    rows = np.random.default_rng(0).choice(q, size=min(64, q), replace=False)
    # the reference: each sampled offset evaluated alone (a single query is evaluated at itself on
    # every path: no table, no interpolation)
    direct = np.array([float(lobe.density(u[i][None])[0]) for i in rows])
    peak = float(np.max(np.asarray(lobe.density(jnp.zeros((1, 2), dtype)), dtype=np.float64)))
    peak = max(peak, float(np.max(np.abs(direct))))
    error = float(np.max(np.abs(np.asarray(values, np.float64)[rows] - direct)) / peak)
    import brdfscale

    shape = lobe.shape
    method = getattr(shape, "discretisation", None)
    label = method.explain() if method is not None else getattr(shape, "method", "closed form")
    return {
        "brdfscale_file": brdfscale.__file__,
        "case": case,
        "dtype": dtype_name,
        "queries": q,
        "evolve_s": evolve_s,
        "first_s": first,
        "warm_s": warm,
        "per_query_warm_s": warm / q,
        "rss_before_bytes": rss_before,
        "rss_peak_bytes": rss_peak,
        "error_vs_direct": error,
        "method": label,
    }


def _run_point(case, dtype, q, baseline=None) -> dict:
    """One point in a fresh process (``python -m experiments.bench_queries --point``). With
    ``baseline`` (a folder holding an exported ``brdfscale/``) the child starts in that folder, so
    that its brdfscale comes first on the path (``-m`` puts the working directory there), and
    finds ``experiments`` through ``PYTHONPATH``; otherwise it starts in the checkout."""
    env, cwd = dict(os.environ), ROOT
    cmd = [sys.executable, "-m", "experiments.bench_queries", "--point", case, dtype, str(q)]
    if baseline:
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
        cwd = baseline
        cmd.append("--baseline")
    try:
        out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env, cwd=cwd, timeout=1800)
    except subprocess.CalledProcessError as err:
        tail = (err.stderr or "").strip().splitlines()[-1:] or ["(no output)"]
        return {"case": case, "dtype": dtype, "queries": q, "failed": tail[0][:300]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--point", nargs=3, metavar=("CASE", "DTYPE", "Q"))
    parser.add_argument("--baseline", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--baseline-rev", default=None, help="git revision to measure at Q = 10², 10³ in the same run")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    if args.point:
        case, dtype, q = args.point
        print(json.dumps(point(case, dtype, int(q))))
        return
    from experiments._bench import machine, write_json

    sizes = [100, 1000, 10**4, 10**5] if args.quick else [100, 1000, 10**4, 10**5, 10**6, 10**7]
    plan = [(c, "float64", q) for c in CASES for q in sizes]
    plan += [(c, "float32", q) for c in CASES for q in ([1000] if args.quick else [1000, 10**6])]
    points = []
    for case, dtype, q in plan:
        print(f"{case:12s} {dtype} Q={q:>9d}", end=" ", flush=True)
        points.append(_run_point(case, dtype, q))
        r = points[-1]
        print(
            r.get("failed")
            or f"warm {r['warm_s']:.4f} s, peak RSS {r['rss_peak_bytes'] / 2**20:.0f} MiB, "
            f"error {r['error_vs_direct']:.2g}"
        )
    baseline = None
    if args.baseline_rev:
        root = ROOT
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run(
                f"git -C '{root}' archive {args.baseline_rev} brdfscale | tar -x -C '{tmp}'", shell=True, check=True
            )
            rev = subprocess.run(
                ["git", "-C", str(root), "rev-parse", args.baseline_rev], check=True, capture_output=True, text=True
            ).stdout.strip()
            baseline = {"revision": rev, "points": []}
            for case in CASES:
                for q in (100, 1000):
                    print(f"baseline {case:12s} Q={q}", end=" ", flush=True)
                    baseline["points"].append(_run_point(case, "float64", q, baseline=tmp))
                    r = baseline["points"][-1]
                    print(
                        r.get("failed") or f"warm {r['warm_s']:.4f} s, peak RSS {r['rss_peak_bytes'] / 2**20:.0f} MiB"
                    )
    readme = _run_point("radial", "float64", 512 * 512)
    payload = {
        "benchmark": "bench_queries",
        "machine": machine(),
        "tol": TOL,
        "tol_float32": TOL32,
        "points": points,
        "baseline": baseline,
        "readme_512": readme,
    }
    path = write_json("bench_queries_quick" if args.quick else "bench_queries", payload)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
