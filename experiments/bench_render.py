"""Benchmark of the brdfscale Mitsuba BSDF (issue 33): renders per second, error per footprint band, eval accuracy.

Three parts, one JSON (experiments/results/bench_render.json):

* ``speed`` — frames per second at study 4's 192 × 128 view of a receding plane (experiments/render_validation.py):
  the micro-geometry ground truth at 1 sample per pixel (the measured di-3 surface as a 512² mesh tiled by instances,
  direct lighting with a shadow ray), and each plane material shading every pixel once (``naive`` and ``lean``:
  Mitsuba's ``roughconductor``; ``brdfscale``: :func:`brdfscale.render.bsdf`, μ from each pixel's footprint). The
  plane timings are the BSDF evaluation of the whole frame (the footprint's mean normal, a mip-map fetch in a
  renderer, is computed beforehand and not timed). Best of ``--repeat`` rounds, after a compiling round.
* ``bands`` — the errors against the micro-geometry truth per footprint band and the time to equal error, read from
  the study's committed results (experiments/results/render_validation/<surface>.json; rerun the study to change
  them), with the target verdicts.
* ``eval_accuracy`` — the plugin's ``eval`` against brdfscale's own lobe: ``brdfscale.evolve(Beckmann(α0), law.at(1),
  law.at(μ))`` evaluated with Smith masking (:meth:`brdfscale.lobes.AbstractLobe.evaluate`, height-correlated
  ``G₂``), the law the di-3 surface's measured one; the material built with ``tolerance=1e-2`` (the ladder refined
  in ln μ and the slope grid refined until their interpolation is within 1e-2 of the evolved lobe: docs/render.md);
  μ at three ladder nodes, at the midpoints of the two finest intervals and at four random scales in [1, 32]. The
  spline form (tricubic B-splines, docs/render.md) on the law's own scales refined with ``tolerance=1e-4``;
  directions whose half-vector slope is drawn from the lobe itself (values that matter), both within 72.5° of the
  normal. Relative errors where the reference exceeds 1e-3 of the largest value.

Targets (issue 33): the brdfscale material's error ≤ ½ of the LEAN material's where the footprint covers ≥ 8 facets
(μ ≥ 8 texels) on the real surface; ≥ 100× faster than the micro-geometry truth at equal error; eval within 1e-4
relative of brdfscale's lobe.

Run:  python -m experiments.bench_render [--repeat 3]
"""

import argparse
import json
import math
import os
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np

import brdfscale as bs
from brdfscale import lobes
from experiments import render_plane, render_validation
from experiments._bench import machine, RESULTS, write_json


SURFACE = "di-3"
TARGET_RATIO = 0.5
TARGET_SPEEDUP = 100.0
TARGET_EVAL = 1e-4
LADDER = 9
EVAL_TOLERANCE = 1e-2  # render.bsdf(tolerance=…): the ladder refined until its ln-μ interpolation is within it
EVAL_NODES = 257  # slope nodes per axis to start from; tolerance refines the grid (nested) where bilinear needs more
SPLINE_NODES = 65  # the spline form's start (its error falls as h⁴: it needs far fewer)


def speed(*, width: int, height: int, size: int, repeat: int) -> dict:
    rv = render_validation
    mi = rv.mitsuba()
    field = rv.height_field(SURFACE, size)
    camera = render_plane.Camera(width, height)
    mu = render_plane.footprints(camera)
    levels = [2**k for k in range(math.ceil(math.log2(max(mu.max(), 2))) + 1) if 2**k <= size // 8]
    level_stats = rv.level_statistics(field, rv.ALPHA0, levels)
    geometry = rv.MicroGeometry(field, camera, rv.ALPHA0)
    slopes = rv.mean_slopes(field, camera, mu, 0)
    geometry.render(1, 0)  # compile
    micro = [geometry.render(1, k + 1)[1] for k in range(repeat)]
    _, planes = rv.render_planes(
        mi, camera, mu, slopes, geometry.light, level_stats, levels, rv.ALPHA0, repeat=repeat
    )  # each the best of `repeat`; brdfscale_t is absent where its evolution is refused
    best = {"micro_geometry_1spp": min(micro), **planes}
    return {
        "image": [width, height],
        "tile_size": size,
        "instances": geometry.instances,
        "triangles_per_tile": geometry.triangles,
        "seconds_best": best,
        "frames_per_second": {k: 1.0 / v for k, v in best.items()},
        "repeat": repeat,
        "micro_geometry_1spp_all_seconds": micro,
    }


def eval_accuracy(*, size: int, n: int, seed: int) -> dict:
    """The plugin's eval against the exactly evolved, Smith-masked lobe, for the material in three forms (module
    docstring): ``closed`` (the default for this Gaussian material: covariances interpolated in ln μ, exact between
    the law's scales, which the default ladder holds), ``table`` (tabulated, refined to ``EVAL_TOLERANCE``) and
    ``spline`` (tabulated, tricubic B-splines, refined to ``TARGET_EVAL``)."""
    rv = render_validation
    mi = rv.mitsuba()
    from brdfscale import render

    field = rv.height_field(SURFACE, size)
    levels = [1, 2, 4, 8, 16, 32]
    law = rv.level_statistics(field, rv.ALPHA0, levels)["law"]
    base = lobes.Beckmann(rv.ALPHA0)
    ladder = [float(x) for x in np.geomspace(1.0, levels[-1], LADDER)]
    forms = {
        "closed": dict(tolerance=TARGET_EVAL),  # default ladder: the law's scales on it
        "table": dict(scales=ladder, size=EVAL_NODES, tolerance=EVAL_TOLERANCE, form="table"),
        # the law's own scales (uniform in ln μ, each a break of the spline ladder), refined to the target
        "spline": dict(scales=levels, size=SPLINE_NODES, tolerance=TARGET_EVAL, form="spline"),
    }
    out = {"surface": SURFACE, "tile_size": size, "forms": {}}
    for form, options in forms.items():
        started = time.perf_counter()
        material = render.bsdf(base, law, mu0=1.0, texel=1.0, variant=rv.VARIANT, **options)
        build_seconds = time.perf_counter() - started
        host = material.host
        refined = [float(x) for x in np.exp(host.log_mu)]
        rng = np.random.default_rng(seed)
        nodes = [refined[0], refined[len(refined) // 2], refined[-1]]
        between = [math.sqrt(a * b) for a, b in zip(refined[:2], refined[1:3])]  # near μ0: the lobe changes fastest
        between += [float(x) for x in np.exp(rng.uniform(0.0, math.log(levels[-1]), 4))]  # random μ in [1, 32]
        records = []
        for where, mus in (("ladder node", nodes), ("between nodes", between)):
            for mu in mus:
                records.append({"mu": mu, "where": where, **eval_errors(mi, material, base, law, mu, rng, n)})
        entry = {
            "options": {k: v for k, v in options.items() if k != "scales"},
            "form": host.form,
            "ladder_levels": len(refined),
            "build_seconds": build_seconds,
            "records": records,
            "max_relative": max(r["max_relative"] for r in records),
            "worst_median_relative": max(r["median_relative"] for r in records),
        }
        if host.form == "table":
            entry["table_nodes"] = int(host.values.shape[1] - 2)  # the refined grid, without the zero ring
            entry["table_bytes_float32"] = int(host.values.nbytes // 2)
        elif host.form == "spline":
            entry["table_nodes"] = int(host.values.shape[1] - 4)  # the refined grid, without the two zero rings
            entry["table_bytes_float32"] = int(host.values.nbytes // 2)  # the sampler's values
            entry["coefficient_bytes_float32"] = int(host.coefficients.nbytes // 2)  # what eval reads
            entry["runs"] = len(host.breaks) - 1
        else:
            entry["parameter_bytes_float32"] = int(host.parameters.nbytes // 2)
        out["forms"][form] = entry
    return out


def eval_errors(mi, material, base, law, mu: float, rng, n: int) -> dict:
    """Relative errors of ``material``'s eval at scale μ against ``brdfscale.evolve(base, law.at(1), law.at(μ))``
    evaluated with height-correlated Smith masking, at directions whose half-vector slope is drawn from the lobe."""
    lobe = bs.evolve(base, law.at(1.0), law.at(mu))
    cov = np.asarray(law.slope_covariance(1.0)) - np.asarray(law.slope_covariance(mu)) + np.asarray(base.shape.cov)
    m = rng.multivariate_normal(np.zeros(2), cov, size=n)
    h = np.concatenate([m, np.ones((n, 1))], 1)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    th, ph = np.arccos(rng.uniform(0.3, 1.0, n)), rng.uniform(0, 2 * np.pi, n)
    o = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], 1)
    i = 2 * (o * h).sum(1, keepdims=True) * h - o
    keep = i[:, 2] > 0.3
    i, o = i[keep], o[keep]
    reference = np.asarray(lobe.evaluate(i, o, masking=lobes.SmithMasking()))
    value = render_validation.shade(mi, material, o, i, np.full(len(o), mu))  # Mitsuba: wi = o, wo = i (light)
    sel = reference > 1e-3 * reference.max()
    rel = np.abs(value[sel] / reference[sel] - 1)
    return {
        "directions": int(sel.sum()),
        "median_relative": float(np.median(rel)),
        "p99_relative": float(np.quantile(rel, 0.99)),
        "max_relative": float(rel.max()),
    }


def bands() -> dict:
    out = {}
    for path in sorted((RESULTS / "render_validation").glob("*.json")):
        d = json.loads(path.read_text())
        out[d["surface"]] = {
            "source": f"experiments/results/render_validation/{path.name}",
            "measured": d["machine"]["date_utc"],
            "bands": {m: d["errors"][m]["bands"] for m in d["errors"]},
            "mu_ge_8": {m: d["errors"][m]["mu_ge_threshold"] for m in d["errors"]},
            "equal_error": d["equal_error"],
        }
    return out


def targets(payload: dict) -> dict:
    out = {}
    real = payload["bands"].get(SURFACE)
    if real is not None:
        lean = real["mu_ge_8"]["lean"]["bias_mean_over_bands"]
        ours = real["mu_ge_8"]["brdfscale"]["bias_mean_over_bands"]
        out["error_half_of_lean_mu_ge_8"] = {
            "brdfscale_bias": ours,
            "lean_bias": lean,
            "ratio": ours / lean,
            "met": ours <= TARGET_RATIO * lean,
        }
        if "brdfscale_t" in real["mu_ge_8"]:
            t = real["mu_ge_8"]["brdfscale_t"]["bias_mean_over_bands"]
            out["error_half_of_lean_mu_ge_8_student_t"] = {
                "brdfscale_bias": t,
                "lean_bias": lean,
                "ratio": t / lean,
                "met": t <= TARGET_RATIO * lean,
            }
        speedups = {k: v["speedup"] for k, v in real["equal_error"]["brdfscale"].items() if isinstance(v, dict)}
        out["speedup_at_equal_error"] = {
            "speedups": speedups,
            "met": all(s is not None and s >= TARGET_SPEEDUP for s in speedups.values()),
        }
    for form, entry in payload["eval_accuracy"]["forms"].items():
        out[f"eval_within_1e-4_{form}"] = {
            "max_relative": entry["max_relative"],
            "worst_median_relative": entry["worst_median_relative"],
            "met": entry["max_relative"] <= TARGET_EVAL,
        }
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=192)
    parser.add_argument("--height", type=int, default=128)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--directions", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="output folder (default experiments/results)")
    parser.add_argument(
        "--refresh-bands",
        action="store_true",
        help="only re-read the study's band errors (after rerunning experiments.render_validation) into the existing "
        "JSON and recompute the verdicts; speed and eval accuracy are kept",
    )
    parser.add_argument(
        "--keep-speed",
        action="store_true",
        help="keep the existing JSON's speed section (marked kept_from its date) and rerun the rest: for runs "
        "without the bench lock's time",
    )
    args = parser.parse_args(argv)
    if args.refresh_bands:
        folder = RESULTS if args.out is None else Path(args.out)
        payload = json.loads((folder / "bench_render.json").read_text())
        payload["bands"] = bands()
        payload["targets"] = targets(payload)
        write_json("bench_render", payload, folder)
        return payload
    started = time.perf_counter()
    folder = RESULTS if args.out is None else Path(args.out)
    if args.keep_speed:
        previous = json.loads((folder / "bench_render.json").read_text())
        kept = {**previous["speed"], "kept_from": previous["machine"]["date_utc"]}
    payload = {
        "machine": machine(),
        "load_average_at_start": list(os.getloadavg()),
        "speed": kept
        if args.keep_speed
        else speed(width=args.width, height=args.height, size=args.size, repeat=args.repeat),
        "eval_accuracy": eval_accuracy(size=min(args.size, 256), n=args.directions, seed=args.seed),
        "bands": bands(),
    }
    payload["targets"] = targets(payload)
    payload["seconds"] = time.perf_counter() - started
    write_json("bench_render", payload, folder)
    return payload


if __name__ == "__main__":
    main()
