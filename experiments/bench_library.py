"""Material libraries: materials per second of a Python loop of ``fitting.fit`` (what a user
writes today), ``fitting.fit_many`` at several batch sizes and (virtual) device counts, and
``brdfscale.library.fit_library`` in-process and on a local Ray instance with 1 and 2 workers.

Every configuration runs in a fresh Python process with no persistent compilation cache, so its
time includes every compilation (the figure a user meets on a new library); the materials are
the mixed-size synthetic library of ``experiments/library_data.py`` (image sizes 16–32 px,
extents 0.4–0.6, 1–2 replicates, five scales), made before the clock starts. Fits use 6 starts
(the command's default). The library runs read the EXR files and write each material's report
without figures (``fit.json``, ``evolved_lobes.exr``), the same work in-process and on Ray.

Targets (issue 20): the batched fit ≥ 10× the loop's throughput at 64 materials on 2 cores,
compile time included; Ray's overhead ≤ 20 % of the in-process time at 64 materials.

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
import jax
jax.config.update("jax_enable_x64", True)
import fitting
from experiments.library_data import material
kind, n = config["kind"], config["materials"]
if kind in ("loop", "batched"):
    data = [fitting.Dataset.from_measurements(material(i)) for i in range(n)]
    model = fitting.ParametricModel()
    t0 = time.perf_counter()
    if kind == "loop":
        results = [fitting.fit(model, d, starts=config["starts"]) for d in data]
        plan = None
    else:
        plan = fitting.explain_plan(model, data, starts=config["starts"], batch=config["batch"])
        results = fitting.fit_many(model, data, starts=config["starts"], batch=config["batch"])
    seconds = time.perf_counter() - t0
    out = {"seconds": seconds, "converged": sum(r.status == "converged" for r in results),
           "theta": [r.theta.tolist() for r in results], "devices": len(jax.devices())}
    if plan is not None:
        out.update(buckets=len(plan.buckets), padding=plan.padding, plan=plan.explain())
else:
    from brdfscale import library
    spec = library.FitSpec(starts=config["starts"])
    t0 = time.perf_counter()
    result = library.fit_library(config["source"], config["out"], spec=spec, batch=config["batch"],
                                 executor=config["executor"], workers=config.get("workers"), progress=False)
    seconds = time.perf_counter() - t0
    out = {"seconds": seconds, "done": result.done, "failed": result.failed}
print("RESULT " + json.dumps(out))
"""


def _run(config: dict, devices: int = 1) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "BRDFSCALE_COMPILATION"))}
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["JAX_PLATFORMS"] = "cpu"
    env["BRDFSCALE_PROGRESS"] = "0"
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(config)], capture_output=True, text=True,
                          env=env, cwd=ROOT)
    wall = time.perf_counter() - t0
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"{config} failed:\n{proc.stderr[-3000:]}")
    out = json.loads(lines[-1][len("RESULT "):])
    out.update(config, process_wall_s=wall, materials_per_s=config["materials"] / out["seconds"], xla_devices=devices)
    print(f"{config['kind']:8s} n={config['materials']:4d} batch={config.get('batch', '-')!s:4s} "
          f"devices={devices} workers={config.get('workers', '-')}: {out['seconds']:.1f} s, "
          f"{out['materials_per_s']:.2f} materials/s", flush=True)
    return out


def run(quick: bool = False, device_counts=(2, 4)) -> dict:
    sizes = [4] if quick else [8, 64, 256]
    loop_sizes = [4] if quick else [8, 64]
    at = 4 if quick else 64
    rows = []
    for n in loop_sizes:
        rows.append(_run({"kind": "loop", "materials": n, "starts": STARTS}))
    for n in sizes:
        rows.append(_run({"kind": "batched", "materials": n, "starts": STARTS, "batch": 64}))
    for batch in ([2] if quick else [16]):
        rows.append(_run({"kind": "batched", "materials": at, "starts": STARTS, "batch": batch}))
    for devices in ([2] if quick else device_counts):
        rows.append(_run({"kind": "batched", "materials": at, "starts": STARTS, "batch": 64}, devices=devices))
    library_rows = []
    with tempfile.TemporaryDirectory() as tmp:
        source = os.path.join(tmp, "library")
        env_child = ("import jax; jax.config.update('jax_enable_x64', True); "
                     f"from experiments.library_data import write_library; write_library({source!r}, {at})")
        subprocess.run([sys.executable, "-c", env_child], check=True, cwd=ROOT, capture_output=True)
        batch = 2 if quick else 16
        configs = [{"executor": "process"}, {"executor": "ray", "workers": 1}, {"executor": "ray", "workers": 2}]
        for k, extra in enumerate(configs):
            config = {"kind": "library", "materials": at, "starts": STARTS, "batch": batch, "source": source,
                      "out": os.path.join(tmp, f"out{k}"), **extra}
            try:
                library_rows.append(_run(config))
            except RuntimeError as err:  # Ray missing or failing: recorded, not hidden
                library_rows.append({**config, "failed": str(err)[-500:]})
    loop = {r["materials"]: r for r in rows if r["kind"] == "loop"}
    batched = next(r for r in rows if r["kind"] == "batched" and r["materials"] == at and r["batch"] == 64
                   and r["xla_devices"] == 1)
    in_process = library_rows[0]
    summary = {"speedup_batched_vs_loop": loop[at]["seconds"] / batched["seconds"],
               "target_speedup": 10.0}
    summary["speedup_met"] = summary["speedup_batched_vs_loop"] >= summary["target_speedup"]
    for r in library_rows[1:]:
        if not isinstance(r.get("failed"), str) and not isinstance(in_process.get("failed"), str):
            r["overhead_vs_in_process"] = r["seconds"] / in_process["seconds"] - 1
    ray1 = library_rows[1]
    if "overhead_vs_in_process" in ray1:
        summary["ray_1_worker_overhead"] = ray1["overhead_vs_in_process"]
        summary["ray_overhead_met"] = ray1["overhead_vs_in_process"] <= 0.20
    # the optimum of each material is the same whichever way it was fitted (solver tolerance)
    import numpy as np

    ref = np.asarray(loop[at]["theta"]) if at in loop else None
    for r in rows:
        if ref is not None and r["materials"] == at:
            r["max_abs_theta_difference_vs_loop"] = float(np.max(np.abs(np.asarray(r["theta"]) - ref)))
        r.pop("theta", None)
    return {"benchmark": "bench_library", "machine": machine(), "quick": quick, "starts": STARTS, "fits": rows,
            "library": library_rows, "summary": summary}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="4 materials, one of each configuration (a smoke run)")
    parser.add_argument("--devices", default="2,4",
                        help="virtual CPU device counts to shard over, comma-separated ('' for none; default 2,4)")
    args = parser.parse_args(argv)
    payload = run(args.quick, tuple(int(x) for x in args.devices.split(",") if x))
    print(json.dumps(payload["summary"], indent=1))
    print("wrote", write_json("bench_library_quick" if args.quick else "bench_library", payload))


if __name__ == "__main__":
    main()
