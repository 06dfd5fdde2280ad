"""Material libraries: materials per second of a Python loop of ``fitting.fit`` (what a user
writes today), ``fitting.fit_many`` at several batch sizes and (virtual) device counts, and the
command ``brdfscale fit-library`` in-process and on Ray.

Fits: every configuration runs in a fresh Python process with no persistent compilation cache,
so its time includes every compilation (the figure a user meets on a new library); the clock
runs from the first fit to the last result. The materials are the mixed-size synthetic library
of ``tests/helpers.py`` (image sizes 16–32 px, extents 0.4–0.6, 1–2 replicates,
five scales), made before the clock starts. Fits use 6 starts (STARTS, given explicitly; the defaults are 8). Each
``fit_many`` configuration is then run once more in the same process, every program compiled:
the difference is the compilation, and the warm time per padded row gives the measured
exchange rate of the bucketing (``compile_rows_measured``: padded rows whose solve costs one
bucket's compilation; ``fitting.COMPILE_ROWS`` is the default).
``fit_many`` runs with the platform's default ``lanes`` (1 on a CPU: each solve by itself)
except in the two ``lanes`` rows: groups of 8 vmapped solves, and all of them vmapped in
lock-step (the accelerators' default) — the measurement behind the CPU default.

Library: the whole command, as a user runs it (Python start-up and imports included), each
configuration with a fresh, empty compilation cache: in-process; a local Ray instance that the
command starts and stops (``--workers 1``, ``2``); and attached with ``--address`` to a Ray
instance already running with 1 CPU (``ray start --head``, timed apart) — Ray's cost per library
on a cluster. They read the EXR files and write each material's report without figures
(``fit.json``, ``evolved_lobes.exr``), the same work in-process and on Ray.

Targets (issue 20): the batched fit ≥ 10× the loop's throughput at 64 materials on 2 cores,
compile time included; Ray's overhead ≤ 20 % of the in-process time at 64 materials (judged on
the attached run; a local instance's start and stop are a fixed cost, reported apart).

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.bench_library   (≈ 12 min on 2 cores)
      python -m experiments.bench_library --quick                          (a smoke run, seconds)
Writes experiments/results/bench_library.json (``_quick`` with --quick); docs/library.md's table
is generated from it by ``python -m experiments.benchmarks_page``.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from experiments._bench import machine, write_json


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STARTS = 6

_CHILD = r"""
import json, os, sys, time
config = json.loads(sys.argv[1])
lanes = config.get("lanes")
import jax
jax.config.update("jax_enable_x64", True)
from brdfscale import fitting
from tests.helpers import material
kind, n = config["kind"], config["materials"]
data = [fitting.Dataset.from_measurements(material(i)) for i in range(n)]
model = fitting.ParametricModel()
t0 = time.perf_counter()
if kind == "loop":
    results = [fitting.fit(model, d, starts=config["starts"]) for d in data]
else:
    results = fitting.fit_many(model, data, starts=config["starts"], batch=config["batch"], lanes=lanes)
seconds = time.perf_counter() - t0
out = {"seconds": seconds, "converged": sum(r.status == "converged" for r in results),
       "theta": [r.theta.tolist() for r in results], "devices": len(jax.devices())}
if kind == "batched":
    # the same call again, every program compiled: what compiling cost, and a padded row's solve
    t0 = time.perf_counter()
    fitting.fit_many(model, data, starts=config["starts"], batch=config["batch"], lanes=lanes)
    warm = time.perf_counter() - t0
    plan = fitting.explain_plan(model, data, starts=config["starts"], batch=config["batch"], lanes=lanes)
    out.update(buckets=len(plan.buckets), lanes_used=sorted({b.lanes for b in plan.buckets}),
               padding=plan.padding, plan=plan.explain(), warm_seconds=warm, rows_padded=plan.rows_padded,
               compile_seconds_per_bucket=(seconds - warm) / len(plan.buckets),
               seconds_per_padded_row=warm / plan.rows_padded)
print("RESULT " + json.dumps(out))
"""


def _run(config: dict, devices: int = 1) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "BRDFSCALE_COMPILATION"))}
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["JAX_PLATFORMS"] = "cpu"
    env["BRDFSCALE_PROGRESS"] = "0"
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, json.dumps(config)], capture_output=True, text=True, env=env, cwd=ROOT
    )
    wall = time.perf_counter() - t0
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"{config} failed:\n{proc.stderr[-3000:]}")
    out = json.loads(lines[-1][len("RESULT ") :])
    out.update(config, process_wall_s=wall, materials_per_s=config["materials"] / out["seconds"], xla_devices=devices)
    print(
        f"{config['kind']:8s} n={config['materials']:4d} batch={config.get('batch', '-')!s:4s} "
        f"lanes={config.get('lanes', 'default')!s:7s} "
        f"devices={devices} workers={config.get('workers', '-')}: {out['seconds']:.1f} s, "
        f"{out['materials_per_s']:.2f} materials/s",
        flush=True,
    )
    return out


def _command(args, env, timeout=1800) -> float:
    """Wall seconds of ``python -m brdfscale ARGS`` (what a user waits: start-up and imports included)."""
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "brdfscale", *args], capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout
    )
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(
            f"brdfscale {' '.join(args)} exited {proc.returncode}:\n{proc.stdout[-1500:]}\n{proc.stderr[-1500:]}"
        )
    return seconds


def _library_rows(n: int, batch: int) -> list:
    """``brdfscale fit-library`` on an n-material library, each configuration a whole command
    (start-up and imports included) with a fresh, empty compilation cache of its own (the
    command's default cache, cold: shared by a run's Ray workers, as on a first library):
    in-process; on a local Ray instance the command starts and stops (--workers 1, 2); and
    attached (--address) to a Ray instance already running with 1 CPU (``ray start --head``,
    its start-up timed apart): Ray's cost per library on a cluster."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        source = os.path.join(tmp, "library")
        make = (
            "import jax; jax.config.update('jax_enable_x64', True); "
            f"from tests.helpers import write_library; write_library({source!r}, {n})"
        )
        subprocess.run([sys.executable, "-c", make], check=True, cwd=ROOT, capture_output=True)
        base = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "RAY_ADDRESS"))}
        base.update(JAX_PLATFORMS="cpu", BRDFSCALE_PROGRESS="0", RAY_USAGE_STATS_ENABLED="0")
        configs = [
            ("in_process", []),
            ("ray_workers_1", ["--workers", "1"]),
            ("ray_workers_2", ["--workers", "2"]),
            ("ray_address_1", ["--address", "auto"]),
        ]
        for k, (how, extra) in enumerate(configs):
            env = {**base, "BRDFSCALE_COMPILATION_CACHE": os.path.join(tmp, f"cache{k}")}
            row = {"how": how, "materials": n, "batch": batch, "starts": STARTS}
            ray_bin = os.path.join(os.path.dirname(sys.executable), "ray")
            try:
                if how == "ray_address_1":
                    t0 = time.perf_counter()
                    subprocess.run(
                        [
                            ray_bin,
                            "start",
                            "--head",
                            "--num-cpus",
                            "1",
                            "--include-dashboard",
                            "false",
                            "--disable-usage-stats",
                        ],
                        check=True,
                        capture_output=True,
                        env=env,
                        timeout=300,
                    )
                    row["ray_start_seconds"] = time.perf_counter() - t0
                try:
                    row["seconds"] = _command(
                        [
                            "fit-library",
                            source,
                            "--out",
                            os.path.join(tmp, f"out{k}"),
                            "--batch",
                            str(batch),
                            "--starts",
                            str(STARTS),
                            "--no-progress",
                            *extra,
                        ],
                        env,
                    )
                finally:
                    if how == "ray_address_1":
                        subprocess.run([ray_bin, "stop", "--force"], capture_output=True, env=env, timeout=300)
                row["materials_per_s"] = n / row["seconds"]
                print(f"library {how:14s} n={n} batch={batch}: {row['seconds']:.1f} s", flush=True)
            except (RuntimeError, OSError, subprocess.SubprocessError) as err:  # Ray missing or failing: recorded
                row["failed"] = str(err)[-500:]
                print(f"library {how}: failed: {row['failed']}", flush=True)
            rows.append(row)
    return rows


def run(quick: bool = False, device_counts=(2, 4)) -> dict:
    sizes = [4] if quick else [8, 64, 256]
    loop_sizes = [4] if quick else [8, 64]
    at = 4 if quick else 64
    rows = []
    for n in loop_sizes:
        rows.append(_run({"kind": "loop", "materials": n, "starts": STARTS}))
    for n in sizes:
        rows.append(_run({"kind": "batched", "materials": n, "starts": STARTS, "batch": 64}))
    for batch in [2] if quick else [16]:
        rows.append(_run({"kind": "batched", "materials": at, "starts": STARTS, "batch": batch}))
    # lanes: the CPU default (1, each solve by itself) against groups and the accelerators' default (all vmapped)
    for lanes in [2, "all"] if quick else [8, "all"]:
        rows.append(_run({"kind": "batched", "materials": at, "starts": STARTS, "batch": 64, "lanes": lanes}))
    for devices in [2] if quick else device_counts:
        rows.append(_run({"kind": "batched", "materials": at, "starts": STARTS, "batch": 64}, devices=devices))
    library_rows = _library_rows(at, 2 if quick else 16)
    loop = {r["materials"]: r for r in rows if r["kind"] == "loop"}
    batched = next(
        r
        for r in rows
        if r["kind"] == "batched"
        and r["materials"] == at
        and r["batch"] == 64
        and r["xla_devices"] == 1
        and "lanes" not in r
    )
    summary = {"speedup_batched_vs_loop": loop[at]["seconds"] / batched["seconds"], "target_speedup": 10.0}
    summary["speedup_met"] = summary["speedup_batched_vs_loop"] >= summary["target_speedup"]
    in_process = library_rows[0]
    for r in library_rows[1:]:
        if "failed" not in r and "failed" not in in_process:
            r["overhead_vs_in_process"] = r["seconds"] / in_process["seconds"] - 1
    for r in library_rows[1:]:
        if "overhead_vs_in_process" in r:
            summary[f"ray_overhead_{r['how']}"] = r["overhead_vs_in_process"]
    attached = next((r for r in library_rows if r["how"] == "ray_address_1"), None)
    if attached is not None and "overhead_vs_in_process" in attached:
        summary["ray_overhead_met"] = attached["overhead_vs_in_process"] <= 0.20
    measured = [
        r
        for r in rows
        if r["kind"] == "batched"
        and r["xla_devices"] == 1
        and r["materials"] == at
        and r["batch"] == 64
        and "lanes" not in r
    ]
    if measured:
        r = measured[0]
        summary["compile_rows_measured"] = r["compile_seconds_per_bucket"] / r["seconds_per_padded_row"]
    # the optimum of each material is the same whichever way it was fitted (solver tolerance)
    import numpy as np

    ref = np.asarray(loop[at]["theta"]) if at in loop else None
    for r in rows:
        if ref is not None and r["materials"] == at:
            r["max_abs_theta_difference_vs_loop"] = float(np.max(np.abs(np.asarray(r["theta"]) - ref)))
        r.pop("theta", None)
    return {
        "benchmark": "bench_library",
        "machine": machine(),
        "quick": quick,
        "starts": STARTS,
        "fits": rows,
        "library": library_rows,
        "summary": summary,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="4 materials, one of each configuration (a smoke run)")
    parser.add_argument(
        "--devices",
        default="2,4",
        help="virtual CPU device counts to shard over, comma-separated ('' for none; default 2,4)",
    )
    args = parser.parse_args(argv)
    payload = run(args.quick, tuple(int(x) for x in args.devices.split(",") if x))
    print(json.dumps(payload["summary"], indent=1))
    print("wrote", write_json("bench_library_quick" if args.quick else "bench_library", payload))


if __name__ == "__main__":
    main()
