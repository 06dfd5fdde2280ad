"""Wall time of ``brdfscale fit`` with its default model (issue 31, item 8): an 8-scale, 65² px
measurement set — by default a synthetic one the default model describes (:func:`synthetic_set`); with
``--real NAME`` README's chain on a real file of tests/data/topographies (:func:`real_set`); with ``--mi-1`` the
earlier set made from mi-1.mi at ``poisson:200:1`` (:func:`measurement_set`) — fitted as a user runs it, a fresh
``python -m brdfscale fit`` process per run.

Runs, each timed from process start to exit:

* ``default``: ``brdfscale fit M.exr --out D`` — the default model (fitting.AnisotropicModel,
  Gaussian base lobe, solver ``auto`` = lm_normal) and the default sampler (``auto``: IMH where the Pareto k̂ of
  its proposal's weights allows, NUTS otherwise; the chosen sampler's default chains and steps; the row records the
  choice) — with a *cold* compilation cache (an empty ``BRDFSCALE_COMPILATION_CACHE``)
  and then *warm* (the same cache, now filled, into another output directory);
* ``default_no_sampling``: the same with ``--steps 0`` (optimisation, Laplace, report), cold and
  warm: ``default − default_no_sampling`` is the sampling's share, ``cold − warm`` the compilation's;
* ``nuts``: ``--sampler nuts`` (the default before auto), cold and warm;
* ``hmc``: ``--sampler hmc`` (static HMC, faster than NUTS on this near-Gaussian posterior),
  cold and warm;
* ``imh``: ``--sampler imh`` (independence Metropolis–Hastings from the Laplace approximation: one log-density
  per step, no gradient), cold and warm — against the default's targets too, said apart;
* ``student_t_no_sampling``: ``--shape student_t --steps 0``, cold and warm;
* ``nonparametric_anisotropic``: ``--model nonparametric_anisotropic --steps 0``, cold.

Targets (issue 31 item 8): default ≤ 60 s cold and ≤ 15 s warm on 2 cores; the non-parametric anisotropic model ≤ 3
min cold — each met only by a run that ends with exit status 0 (in time and converged). The machine's load average
is recorded before and after every run (the wall times are only as good as the machine was idle), and so is the CPU
time the run's process used (user + system, all its threads): on a loaded machine the wall time grows with the
load, the CPU time far less — it bounds what the run needs of an idle machine's cores.

Run: ``flock /tmp/brdfscale-bench.lock python -m experiments.bench_anisotropic [--quick] [--real NAME]``
(writes experiments/results/bench_anisotropic.json, with ``--real`` bench_anisotropic_real.json: the runs
:data:`REAL_RUNS` only; ``--quick`` leaves out the non-parametric
model and the Student-t shape; ``--only NAME[,NAME]`` runs those runs alone and merges them into the
existing JSON, each row with its own date and load; ``--timeout S`` kills a run after S seconds and
records it as timed out).

The synthetic set is built here, not imported: experiments never import tests, and this set is the
benchmark's own definition (8 scales, 65² px); tests/helpers.py's ``noisy_dataset`` builds the tests'
smaller sets of the same kind.
"""

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments._bench import code_commit, machine, RESULTS, write_json


ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"default_cold_s": 60.0, "default_warm_s": 15.0, "nonparametric_anisotropic_cold_s": 180.0}


def measurement_set(path: Path) -> dict:
    """The 8-scale, 65² px set of mi-1 (as before this benchmark's rewrite) written to ``path``."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from brdfscale import exr, synth, topography

    field = topography.read(str(ROOT / "tests/data/topographies/mi-1.mi"))
    mus = field.scales(8, smallest=2)
    stats = synth.facet_statistics(field, mus, bins=17)
    spread = max(float(np.max(np.diag(stats[0].covariance - s.covariance))) for s in stats)
    mset = synth.gonioreflectometer(
        field, mus, [0.0, 0.0, 1.0], extent=4 * spread**0.5, pixels=65, noise=synth.PoissonNoise(200, 1), seed=1
    )
    exr.write_measurements(str(path), mset)
    return {"file": "tests/data/topographies/mi-1.mi", "scales": len(mus), "pixels": 65, "noise": "poisson:200:1"}


REAL_NOISE = "poisson:0.05:1"
"""The real set's noise: at 0.05 counts per unit of the lobe the default model is adequate to the images (at
``poisson:200:1`` its fits of the real files are inadequate and not sampled: docs/benchmarks.md), so the run times
the whole default fit, sampling included."""


def real_set(path: Path, name: str) -> dict:
    """README's chain on the real file ``tests/data/topographies/NAME``: ``brdfscale synth --topography FILE --noise
    REAL_NOISE --out`` (synth's defaults: 8 scales, 65² px), written again without the synthesised surface's record
    (metadata ``truth``) — the file as an instrument would hand it over, which records no surface to test the fit's ΔΣ
    against (fitting.assess's ``covariance_truth``; a fit that misses that truth is not sampled, so it would time
    no sampling)."""
    from brdfscale import exr, MeasurementSet

    source = ROOT / "tests/data/topographies" / name
    made = path.with_name("synth.exr")
    subprocess.run(
        [sys.executable, "-m", "brdfscale", "synth", "--topography", str(source), "--noise", REAL_NOISE, "--out", made],
        check=True,
        capture_output=True,
    )
    mset = exr.read_measurements(str(made))
    exr.write_measurements(
        str(path), MeasurementSet(mset.images, {k: v for k, v in mset.metadata.items() if k != "truth"})
    )
    sizes = {int(np.shape(image.values)[0]) for image in mset.images}
    return {
        "file": f"tests/data/topographies/{name} (brdfscale synth, its surface's record removed)",
        "real": name,  # the --real argument, which docs/fitting.md's table names
        "scales": len({float(image.mu) for image in mset.images}),
        "pixels": max(sizes),
        "noise": REAL_NOISE,
    }


def synthetic_set(path: Path) -> dict:
    """An 8-scale, 65² px set the default model describes: anisotropic Gaussian lobes of a rotated
    base covariance C0 whose covariance grows by a rotated positive step per scale (the truth of
    tests/helpers.py's ANISO_TRUTH, continued to 8 scales), 1 % Gaussian noise of each image's
    peak plus a floor of 1e-3 — the set on which the default fit is adequate, so that its
    timing is that of a fit that works (mi-1's set is not: its fit is inadequate, exit 5)."""
    import brdfscale as bs

    rng = np.random.default_rng(1)
    x = np.linspace(-0.5, 0.5, 65)
    u = np.stack(np.meshgrid(x, x), axis=-1)

    def rotation(phi):
        c, s = np.cos(phi), np.sin(phi)
        return np.array([[c, -s], [s, c]])

    mean, c0, amplitude = np.array([0.03, -0.02]), rotation(0.4) @ np.diag([0.004, 0.001]) @ rotation(0.4).T, 2.0
    mus = [2.0 ** (k / 2) for k in range(8)]
    images, cov = [], c0
    for k, mu in enumerate(mus):
        if k:
            cov = cov + rotation(0.3 - 0.1 * k) @ np.diag([0.0015, 0.0005]) @ rotation(0.3 - 0.1 * k).T
        d = u - mean
        q = np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d)
        v = amplitude * np.exp(-q / 2) / (2 * np.pi * np.sqrt(np.linalg.det(cov)))
        sigma = 0.01 * v.max() + 1e-3
        images.append(
            bs.LobeImage(
                mu=mu,
                incident=[0.0, 0.0, 1.0],
                extent=0.5,
                values=v + sigma * rng.standard_normal(v.shape),
                sigma=np.full(v.shape, sigma),
            )
        )
    bs.exr.write_measurements(str(path), bs.MeasurementSet(tuple(images)))
    return {
        "file": "synthetic anisotropic Gaussian (experiments/bench_anisotropic.py synthetic_set)",
        "scales": 8,
        "pixels": 65,
        "noise": "gaussian 1 % of peak + 1e-3",
    }


def run(args: list[str], cache: Path, out: Path, timeout: float | None = None) -> dict:
    """One ``python -m brdfscale fit`` process: wall time, CPU time, exit status, load before and
    after, the report's figures; a process still running after ``timeout`` seconds is killed and
    recorded as such (``timed_out``: its wall time is then a lower bound)."""
    env = {**os.environ, "BRDFSCALE_COMPILATION_CACHE": str(cache), "BRDFSCALE_PROGRESS": "0"}
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    command = [sys.executable, "-m", "brdfscale", "fit", *args, "--out", str(out), "--no-progress"]
    try:
        done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT, check=False, timeout=timeout)
        code, stderr, timed_out = done.returncode, done.stderr, False
    except subprocess.TimeoutExpired as err:
        code, timed_out = None, True
        stderr = err.stderr.decode(errors="replace") if isinstance(err.stderr, bytes) else (err.stderr or "")
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    row = {
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "exit": code,
        "timed_out": timed_out,
        "load_1min_before": round(load, 2),
        "load_1min_after": round(os.getloadavg()[0], 2),
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "code_commit": code_commit(),  # --only merges rows of several runs: each names its code
    }
    report = out / "fit.json"
    if report.exists():
        doc = json.loads(report.read_text())
        opt, mcmc = doc.get("optimisation") or {}, doc.get("mcmc") or {}
        row.update(
            parameters=len(doc.get("parameters") or {}),
            solver=(doc.get("model") or {}).get("solver"),
            fit_status=opt.get("status"),
            reduced_chi2=opt.get("reduced_chi2"),
            sampler=mcmc.get("sampler"),
            chosen_by=mcmc.get("chosen_by"),
            sampler_status=mcmc.get("status"),
            outcome=(doc.get("outcome") or {}).get("status"),
        )
        if mcmc:
            summary, checked = mcmc.get("summary") or {}, (mcmc.get("criteria") or {}).get("checked") or []
            ess = [summary[n]["ess_bulk"] for n in checked if n in summary]
            rhat = [summary[n]["r_hat"] for n in checked if n in summary]
            row.update(
                steps=mcmc.get("steps"),
                burn_in=mcmc.get("burn_in"),
                chains=mcmc.get("chains"),
                timing_s=mcmc.get("timing_s"),
                min_ess_bulk=round(min(ess), 1) if ess else None,
                max_r_hat=round(max(rhat), 5) if rhat else None,
                ess_margin=round(min(ess) / (mcmc.get("criteria") or {})["ess_bulk_min"], 2) if ess else None,
            )
    else:
        row["stderr_tail"] = stderr[-400:]
    print(json.dumps(row), flush=True)
    return row


RUNS = {
    "default": [],
    "default_no_sampling": ["--steps", "0"],
    "nuts": ["--sampler", "nuts"],
    "hmc": ["--sampler", "hmc"],
    "imh": ["--sampler", "imh"],
    "nonparametric_anisotropic": ["--model", "nonparametric_anisotropic", "--steps", "0"],
    "student_t_no_sampling": ["--shape", "student_t", "--steps", "0"],
}
QUICK = ("default", "default_no_sampling", "nuts", "hmc", "imh")
REAL_RUNS = ("default", "default_no_sampling", "nuts")


def images_digest(path: Path) -> str:
    """SHA-256 of a measurement set's images (scales, values, σ and masks in file order): what the rows of one JSON
    must share to be merged (the file's metadata, e.g. its provenance, may differ between two writes of one set)."""
    import hashlib

    from brdfscale import exr

    digest = hashlib.sha256()
    for image in exr.read_measurements(str(path)).images:
        for part in (image.mu, image.values, image.sigma, image.mask):
            digest.update(b"-" if part is None else np.ascontiguousarray(np.asarray(part, dtype=float)).tobytes())
    return digest.hexdigest()


def mergeable(name: str, measurements: dict, folder: Path = RESULTS) -> dict | None:
    """The JSON ``folder/name.json`` that ``--only``'s rows join, or None where there is none: refused (SystemExit)
    where its rows were measured on another set — a description that differs, or images of another digest (a JSON
    without one, written before it was recorded, is judged by its description)."""
    previous = folder / f"{name}.json"
    if not previous.exists():
        return None
    merged = json.loads(previous.read_text())
    before = merged.get("measurements", {})
    differs = [k for k in before if before[k] != measurements.get(k)]
    if differs:
        raise SystemExit(
            f"--only: {previous} holds runs of another set ({', '.join(differs)} differ: {before}); run them all again"
        )
    return merged


def _name(mi1: bool, real: str | None) -> str:
    return "bench_anisotropic_mi1" if mi1 else "bench_anisotropic_real" if real else "bench_anisotropic"


def main(
    quick: bool = False,
    mi1: bool = False,
    only: tuple[str, ...] | None = None,
    timeout: float | None = None,
    real: str | None = None,
) -> dict:
    names = only or (REAL_RUNS if real else QUICK if quick else tuple(RUNS))
    runs = {name: RUNS[name] for name in names}
    results: dict = {"machine": machine(), "command": "python -m brdfscale fit M.exr --out D --no-progress [ARGS]"}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if real:
            results["measurements"] = real_set(tmp / "m.exr", real)
        else:
            results["measurements"] = (measurement_set if mi1 else synthetic_set)(tmp / "m.exr")
        results["measurements"]["images_sha256"] = images_digest(tmp / "m.exr")
        if only is not None:
            mergeable(_name(mi1, real), results["measurements"])  # refused before the runs, not after
        results["runs"] = {}
        for name, extra in runs.items():
            cache = tmp / f"cache-{name}"
            cold = run([str(tmp / "m.exr"), *extra], cache, tmp / f"{name}-cold", timeout)
            entry = {"args": extra, "cold": cold}
            if name != "nonparametric_anisotropic":
                entry["warm"] = run([str(tmp / "m.exr"), *extra], cache, tmp / f"{name}-warm", timeout)
            results["runs"][name] = entry
            if only is None:  # what has run, if stopped (--only merges at the end)
                write_json(_name(mi1, real), {**results, "complete": False})
    results["complete"] = True
    return summarise(results)


def summarise(results: dict) -> dict:
    """The profile (compilation, sampling, fit and report) and the targets met, from the runs there are."""
    r = results["runs"]
    if not {"default", "default_no_sampling"} <= set(r):
        return results
    results["profile"] = {
        "compilation_s (default: cold − warm)": round(
            r["default"]["cold"]["wall_s"] - r["default"]["warm"]["wall_s"], 2
        ),
        "sampling_warm_s (default − no sampling, warm)": round(
            r["default"]["warm"]["wall_s"] - r["default_no_sampling"]["warm"]["wall_s"], 2
        ),
        "fit_and_report_warm_s (no sampling, warm)": r["default_no_sampling"]["warm"]["wall_s"],
    }

    def within(row: dict, target: str) -> bool:
        """In time, and a fit that ended well: exit 0 (a run that stopped early or did not converge meets no target)."""
        return not row.get("timed_out") and row["exit"] == 0 and row["wall_s"] <= TARGETS[target]

    met = {
        "default_cold_s": within(r["default"]["cold"], "default_cold_s"),
        "default_warm_s": within(r["default"]["warm"], "default_warm_s"),
    }
    if "imh" in r and "warm" in r["imh"]:  # the default's targets, met by another sampler: said apart
        met["imh_cold_s (--sampler imh, not the default)"] = within(r["imh"]["cold"], "default_cold_s")
        met["imh_warm_s (--sampler imh, not the default)"] = within(r["imh"]["warm"], "default_warm_s")
    if "nonparametric_anisotropic" in r:
        met["nonparametric_anisotropic_cold_s"] = within(
            r["nonparametric_anisotropic"]["cold"], "nonparametric_anisotropic_cold_s"
        )
    results["targets"], results["met"] = TARGETS, met
    return results


if __name__ == "__main__":
    mi1 = "--mi-1" in sys.argv[1:]
    real = None
    if "--real" in sys.argv[1:]:
        at = sys.argv.index("--real") + 1
        real = sys.argv[at] if at < len(sys.argv) else ""
        if not real or not (ROOT / "tests/data/topographies" / real).is_file():
            raise SystemExit(f"--real NAME: a file of tests/data/topographies; got {real!r}")
        if mi1:
            raise SystemExit("--real and --mi-1 are two sets: give one")
    only = None
    if "--only" in sys.argv[1:]:
        only = tuple(sys.argv[sys.argv.index("--only") + 1].split(","))
        unknown = [n for n in only if n not in RUNS]
        if unknown:
            raise SystemExit(f"--only: unknown runs {unknown}; known: {list(RUNS)}")
    timeout = float(sys.argv[sys.argv.index("--timeout") + 1]) if "--timeout" in sys.argv[1:] else None
    out = main("--quick" in sys.argv[1:], mi1, only, timeout, real)
    name = _name(mi1, real)
    if only and (merged := mergeable(name, out["measurements"])) is not None:  # joins the last full or quick run
        merged["measurements"] = out["measurements"]  # the same set, described as this code describes it
        merged["runs"].update(out["runs"])
        out = summarise(merged)
    print(json.dumps(out.get("profile"), indent=1), json.dumps(out.get("met")))
    print("wrote", write_json(name, out))
