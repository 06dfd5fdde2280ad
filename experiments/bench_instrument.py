"""Benchmark of the ray-traced gonioreflectometer (issue 32): speed by Mitsuba variant, a full measurement's wall
time, and the masking-aware model against the instrument.

1. **Rays per second** of :func:`brdfscale.instrument.measure` on a 512² Gaussian field (rms slope 0.2, one scale,
   one incidence, 65² px), by variant (``scalar_rgb``, ``llvm_ad_rgb``, and ``cuda_ad_rgb`` where a GPU is found),
   each in its own process (Mitsuba's variant is process-wide) with Dr.Jit limited to ``--threads`` threads (2:
   the issue's "2 cores"); the best of ``REPEAT`` runs after a warm-up run (compilation), and the first run's
   time with compilation.
2. **The issue's measurement**: 8 scales (log-spaced 4 … 512 px), 65² px images, three incidences (0°, 40°, 70°)
   of a 512² field at the default variant and the instrument's default rays and bounces: wall time (target
   ≤ 10 minutes on 2 cores) and peak resident memory.
3. **Masking-aware model against the instrument**: Gaussian fields (256² px, ℓ = 8 px) of rms slope 0.1, 0.2 and
   0.3, incidences 0°, 40°, 60°, 70°, 80°, the largest scale (the whole roughness in the spot), bounces 3: the
   energy ratio model ÷ instrument of the seed's nearly-flat model and of the masking-aware model (× Smith G₂),
   from experiments/instrument_study.py's predictions (Smith's Λ of the tabulated within-facet lobe), with the
   relative L1 error of each image and the L1 that the instrument's Monte Carlo noise alone gives (``mc_l1_floor``:
   with nearest-node binning the pixels' errors are independent, and an L1 at the floor is noise). Target: the
   masking-aware model within 2 % or twice the Monte Carlo error wherever the seed-only model is off by more than 10 %.

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.bench_instrument [--threads 2] [--quick]
Writes experiments/results/bench_instrument.json (the table of docs/benchmarks.md: experiments/benchmarks_page.py).
``--only PART[,PART]`` (``speed``, ``full``, ``accuracy``) runs those parts alone and merges them into the committed
JSON, as bench_anisotropic's ``--only`` does: parts 1 and 2 report wall times (run them under the bench lock on an
idle machine), part 3 only accuracy (``nice -n 10 python -m experiments.bench_instrument --only accuracy``, no lock).
Each part records its own date, load average at its start and end, and wall time (``parts``), and ``--note TEXT`` a
line on the conditions it ran in (shown with the table).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

from experiments._bench import machine, RESULTS, write_json


VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
SPEED_SIZE, SPEED_RAYS = 512, 100_000
REPEAT = 2
FULL_SIZE, FULL_SCALES, FULL_INCIDENCE = 512, 8, (0.0, 40.0, 70.0)
ACCURACY_SIZE, ACCURACY_SLOPES, ACCURACY_INCIDENCE = 256, (0.1, 0.2, 0.3), (0.0, 40.0, 60.0, 70.0, 80.0)
ACCURACY_RAYS, ACCURACY_BOUNCES = 100_000, 3
ACCURACY_MESHES = ("triangles", "pixel_facets")
TARGET_MESH = "triangles"
"""The mesh the accuracy target is judged on: the continuous surface, every facet of which is in the slope density
Smith's Λ is computed from. The pixel-facet mesh adds vertical walls at every pixel edge, which are in no slope
density and intercept 2–5 % more light at 70–80° (docs/masking.md); its rows are reported beside."""
TARGET_SECONDS = 600.0
PARTS = ("speed", "full", "accuracy")


def _limit_threads(threads: int) -> None:
    import drjit as dr

    dr.set_thread_count(threads)


def speed(variant: str, *, size: int, rays: int, threads: int) -> dict:
    """Rays per second of one variant (run in a process of its own: ``--speed VARIANT``)."""
    from brdfscale import _mitsuba, instrument
    from experiments.instrument_study import gaussian_surface, incident_directions

    problem = _mitsuba.available(variant)
    if problem is not None:
        return {"variant": variant, "skipped": problem}
    _limit_threads(threads)
    field = gaussian_surface(0.2, size=size)
    incident = incident_directions([30.0])

    def once():
        t0 = time.perf_counter()
        instrument.measure(
            field, [float(size)], incident, extent=0.6, pixels=65, rays=rays, seed=0, variant=variant, progress=False
        )
        return time.perf_counter() - t0

    first = once()
    times = sorted(once() for _ in range(REPEAT))
    return {
        "variant": variant,
        "threads": threads,
        "field": f"{size}² Gaussian, rms slope 0.2",
        "rays": rays,
        "first_run_s": round(first, 3),
        "best_s": round(times[0], 3),
        "median_s": round(times[len(times) // 2], 3),
        "rays_per_second": rays / times[0],
    }


def _in_process(flag: str, value: str, threads: int, quick: bool) -> dict:
    argv = [sys.executable, "-m", "experiments.bench_instrument", flag, value, "--threads", str(threads)]
    run = subprocess.run([*argv, *(["--quick"] if quick else [])], capture_output=True, text=True, timeout=3600)
    if run.returncode != 0:
        return {flag.strip("-"): value, "failed": (run.stderr.strip().splitlines() or ["(no message)"])[-1][:300]}
    return json.loads(run.stdout.strip().splitlines()[-1])


def full(*, size: int, scales: int, threads: int) -> dict:
    """The issue's measurement: ``scales`` log-spaced scales, 65² px, three incidences of a ``size``² field."""
    from brdfscale import instrument
    from experiments.instrument_study import gaussian_surface, incident_directions

    _limit_threads(threads)
    field = gaussian_surface(0.2, size=size)
    mus = [float(m) for m in np.unique(np.geomspace(4, size, scales).round())]
    t0 = time.perf_counter()
    mset = instrument.measure(
        field, mus, incident_directions(FULL_INCIDENCE), extent=0.6, pixels=65, seed=0, progress=False
    )
    seconds = time.perf_counter() - t0
    return {
        "field": f"{size}² Gaussian, rms slope 0.2",
        "scales_px": mus,
        "incidence_deg": list(FULL_INCIDENCE),
        "pixels": 65,
        "images": len(mset.images),
        "instrument": {
            k: mset.metadata["instrument"].get(k) for k in ("variant", "mitsuba", "rays", "batches", "bounces")
        },
        "threads": threads,
        "seconds": round(seconds, 1),
        "max_rss_MiB": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "target_seconds": TARGET_SECONDS,
    }


def accuracy(*, size: int, slopes, thetas, rays: int, bounces: int, meshes=ACCURACY_MESHES) -> list:
    """Energy ratios model ÷ instrument of the seed-only and masking-aware models at the largest scale, on each of
    the instrument's meshes."""
    from brdfscale import instrument, synth
    from experiments.instrument_study import escape_record, gaussian_surface, incident_directions, predictions, scores

    rows = []
    for mesh, rms in ((mesh, rms) for mesh in meshes for rms in slopes):
        field = gaussian_surface(rms, size=size)
        extent = synth.robust_extent(field)
        incident = incident_directions(thetas)
        mus = [float(size)]
        mset = instrument.measure(
            field,
            mus,
            incident,
            extent=extent,
            pixels=65,
            rays=rays,
            bounces=bounces,
            seed=0,
            progress=False,
            surface=mesh,
        )
        model = predictions(field, mus, incident, extent, 65, mesh)
        for k, image in enumerate(mset.images):
            seed, masking = scores(model["seed"][k], image), scores(model["masking"][k], image)
            ms = scores(model["masking_ms"][k], image)
            rows.append(
                {
                    "mesh": mesh,
                    "rms_slope": rms,
                    "theta_i_deg": thetas[k],
                    "seed_energy_ratio": seed["energy_ratio"],
                    "masking_energy_ratio": masking["energy_ratio"],
                    "masking_ms_energy_ratio": ms["energy_ratio"],
                    "mc_energy": seed["mc_energy"],
                    "seed_l1": seed["l1"],
                    "masking_l1": masking["l1"],
                    "masking_ms_l1": ms["l1"],
                    "mc_l1_floor": seed["mc_l1_floor"],
                    "escaped_by_order": escape_record(mset, k)["escaped_by_order"],
                }
            )
    return rows


def verdict(rows: list, model: str = "masking_ms") -> dict:
    """Is ``model`` within 2 % (or 2 MC errors) of the instrument wherever the seed-only model is off by more than
    10 %? Rows of one mesh."""

    def within(r):
        return abs(r[f"{model}_energy_ratio"] - 1) <= max(0.02, 2 * r["mc_energy"])

    seed_off = [r for r in rows if abs(r["seed_energy_ratio"] - 1) > 0.10]
    return {
        "rows": len(rows),
        "within": sum(within(r) for r in rows),
        "seed_off_by_more_than_10pc": len(seed_off),
        "within_where_seed_off": sum(within(r) for r in seed_off),
        "failing": [
            [r["rms_slope"], r["theta_i_deg"], round(r[f"{model}_energy_ratio"], 4)] for r in rows if not within(r)
        ],
        "met": bool(seed_off) and all(within(r) for r in seed_off),
    }


def verdicts(rows: list) -> dict:
    """:func:`verdict` per mesh and model (``masking``: single scattering, ``masking_ms``: with the multiply scattered
    light); the target is judged on ``TARGET_MESH`` (module docstring)."""
    meshes = sorted({r["mesh"] for r in rows})
    out = {
        mesh: {m: verdict([r for r in rows if r["mesh"] == mesh], m) for m in ("masking", "masking_ms")}
        for mesh in meshes
    }
    out["target_mesh"] = TARGET_MESH
    out["met"] = TARGET_MESH in out and out[TARGET_MESH]["masking_ms"]["met"]
    return out


def merged(previous: dict, record: dict, only) -> dict:
    """``previous`` (a committed JSON) with the parts ``only`` of ``record`` in place of its own, their conditions
    (``parts``) added to its, and ``record``'s machine (the versions that ran last)."""
    parts = {**previous.get("parts", {}), **{part: record["parts"][part] for part in only}}
    return {**previous, "machine": record["machine"], **{part: record[part] for part in only}, "parts": parts}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2, help="Dr.Jit threads (default 2: the issue's 2 cores)")
    parser.add_argument("--quick", action="store_true", help="small sizes (a smoke run; not the committed JSON)")
    parser.add_argument("--speed", metavar="VARIANT", help=argparse.SUPPRESS)  # one variant, in its own process
    parser.add_argument("--full", metavar="SIZE", help=argparse.SUPPRESS)
    parser.add_argument("--out", default=None, help="write the JSON here instead of experiments/results/")
    parser.add_argument(
        "--only", default=None, help=f"comma-separated parts of {PARTS} to run, merged into the committed JSON"
    )
    parser.add_argument("--note", default=None, help="a line on the conditions of this run, kept with each part")
    args = parser.parse_args(argv)
    only = PARTS if args.only is None else tuple(args.only.split(","))
    unknown = [p for p in only if p not in PARTS]
    if unknown or not only:
        parser.error(f"--only: unknown parts {unknown}; known: {list(PARTS)}")
    quick = args.quick
    if args.speed:
        size, rays = (64, 2_000) if quick else (SPEED_SIZE, SPEED_RAYS)
        print(json.dumps(speed(args.speed, size=size, rays=rays, threads=args.threads)))
        return
    if args.full:
        print(json.dumps(full(size=int(args.full), scales=3 if quick else FULL_SCALES, threads=args.threads)))
        return
    started = time.perf_counter()
    record = {"machine": machine(), "load_average_at_start": list(os.getloadavg()), "parts": {}}

    def accuracy_part():
        rows = accuracy(
            size=32 if quick else ACCURACY_SIZE,
            slopes=ACCURACY_SLOPES[-1:] if quick else ACCURACY_SLOPES,
            thetas=(0.0, 80.0) if quick else ACCURACY_INCIDENCE,
            rays=2_000 if quick else ACCURACY_RAYS,
            bounces=ACCURACY_BOUNCES,
        )
        return {"rows": rows, "verdict": verdicts(rows), "rays": ACCURACY_RAYS, "bounces": ACCURACY_BOUNCES}

    run = {
        "speed": lambda: [_in_process("--speed", v, args.threads, quick) for v in VARIANTS],
        "full": lambda: _in_process("--full", str(64 if quick else FULL_SIZE), args.threads, quick),
        "accuracy": accuracy_part,
    }
    for part in only:
        conditions = {"date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        conditions["load_average_at_start"] = list(os.getloadavg())
        t0 = time.perf_counter()
        record[part] = run[part]()
        conditions["seconds"] = round(time.perf_counter() - t0, 1)
        conditions["load_average_at_end"] = list(os.getloadavg())
        if args.note:
            conditions["note"] = args.note
        record["parts"][part] = conditions
    record["seconds"] = round(time.perf_counter() - started, 1)
    if only != PARTS and not (args.out or quick):  # merged into the committed JSON: its other parts are kept
        record = merged(json.loads((RESULTS / "bench_instrument.json").read_text()), record, only)
    if args.out or quick:
        path = args.out or os.devnull
        with open(path, "w") as f:
            json.dump(record, f, indent=2, default=str)
    else:
        path = write_json("bench_instrument", record)
    print(json.dumps({k: v for k, v in record.items() if k != "machine"}, indent=2, default=str))
    print(f"written to {path}")


if __name__ == "__main__":
    main()
