"""Run time versus error of every evolution path, where the planner lands, and a rendering workload.

Reference problems (each a material evaluated at a few scales μ and offsets u, with an answer
computed independently of brdfscale's evolution code; tests/references/planner.py, shared with
tests/test_scene.py):

* ``closed_form``   — Beckmann lobe, Beckmann statistics: Gaussian variances add (exact);
* ``beckmann_ggx``  — Beckmann lobe, GGX statistics: Hankel integral by SciPy Gauss–Legendre
  quadrature with SciPy's K₁, J₀ (checked against mpmath at one point per scale);
* ``skewed_mixture`` — Beckmann lobe, skewed zero-mean two-Gaussian statistics: the 2D inverse
  Fourier integral by a tensor Gauss–Legendre rule in NumPy;
* ``disk``          — Beckmann lobe, statistics that dilute a uniform disk of slopes with flat
  facets (``f Disk + (1 − f) δ``): Hankel integral by SciPy quadrature (and mpmath);
* ``plus``          — Beckmann lobe, nearly-specular statistics ``(1 − w) δ + c h_0 + w Beckmann``
  with the plus-distribution h_0 (seed §6): Hankel integral by SciPy quadrature with H_0 from
  its power series (checked against mpmath);
* ``so3``           — an anisotropic Beckmann facet lobe (α = 0.3 / 0.15 along the facet's
  tangent / bitangent) as a function of the facet orientation Γ ∈ SO(3), isotropic
  rotational-diffusion statistics, queries at tilted and twisted global orientations Γ∞:
  the group integral ``∫ ρ_μ0(Γ∞Δ) k(Δ) dΔ`` against the SO(3) heat kernel (character sum) by a
  tensor Gauss–Legendre rule in exponential coordinates with SciPy's rotations (its
  convergence, 48 versus 64 nodes per axis, is recorded in the JSON).

For each problem every path's accuracy knobs are swept — ``evolve(..., method, size, tol)``
for the radial (Gauss–Legendre nodes × cut-off tolerance) and grid (side × tolerance) paths,
the closed form where it applies, and for ``so3`` the public SO(3) pipeline (``so3.forward`` →
``so3.evolve_diffusion`` → ``so3.synthesize``) at band limits 16 … 64 — recording (time, max error
relative to the lobe's peak at each scale) and the Pareto front; then the planner
(:func:`brdfscale.scene.plan`) at several error targets, with the ratio of its time to the
Pareto-optimal time at the error it reaches.

Cost model: the planner's predicted cost is in relative units (:mod:`brdfscale.scene._cost`).
For every slope-space problem each applicable path is forced at tol = 1e-6 and the predicted
order of their costs is compared with the measured order of their times; over every plan
timed, the Spearman rank correlation between predicted units and measured seconds and the
range of seconds per unit are recorded (``cost_model`` in the JSON).

Workload: a camera looking at a checkerboard plane receding to the horizon (two materials:
Beckmann lobe with GGX statistics, and with Beckmann statistics), μ from the pixel footprint.
Planner (plan + jit-compiled evaluation) versus naive per-pixel grid evaluation (the
library's ``evolve(..., method="grid", tol)`` at each pixel's own μ, its ``density`` at the
pixel's offset; timed on a random sample of pixels and extrapolated to the image, lobe
construction and size choice not counted). Errors against a per-pixel SciPy Hankel reference.

Run: ``flock /tmp/brdfscale-bench.lock python -m experiments.bench_planner`` (``--quick`` for the
smoke version) → experiments/results/bench_planner.json and bench_planner_*.png; the load
average before and after is recorded.
"""

import argparse
import math
import os
import time

import jax


jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import brdfscale as bs  # noqa: E402
from brdfscale import scene, so3  # noqa: E402
from brdfscale.geometry import microfacet_factor, slope_to_direction  # noqa: E402
from experiments._bench import best_time, machine, RESULTS, write_json  # noqa: E402
from tests.references.planner import (  # noqa: E402 — the independent references, shared with tests/test_scene.py
    _hankel_rows,
    alpha,
    hankel_reference,
    LOBE_ALPHA,
    material,
    mpmath_check,
    MU0,
    plus_h0,
    PLUS_X0,
    reference,
    so3_material,
    so3_problem,
    so3_reference,
    WIDTH,
)


# -- problems ---------------------------------------------------------------------------------------
def offsets(kind, n):
    """Query offsets: a polar set around the lobe (radial problems) or a 2D grid (skewed)."""
    reach = 0.15
    if kind == "skewed_mixture":
        g = np.linspace(-reach, reach, n)
        return np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    r = np.linspace(0, reach, n * n)
    phi = np.linspace(0, 2 * np.pi, n * n, endpoint=False) * 7.3
    return np.stack([r * np.cos(phi), r * np.sin(phi)], -1)


def problem_queries(kind, mus, n):
    u = offsets(kind, n)
    U = np.concatenate([u] * len(mus))
    M = np.repeat(mus, len(u))
    d = np.asarray(slope_to_direction(jnp.asarray(U)))
    ref = np.concatenate([reference(kind, mu, u) for mu in mus])
    peak = np.repeat([np.max(np.abs(reference(kind, mu, u))) for mu in mus], len(u))
    return U, M, d, ref, peak


def relative_error(values, ref, peak):
    return float(np.max(np.abs(np.asarray(values) - ref) / peak))


def sweep_point(mat, kind, mus, U, ref, peak, method, size, tol, repeat):
    groups = [np.flatnonzero(np.repeat(mus, len(U) // len(mus)) == mu) for mu in mus]

    @eqx.filter_jit
    def run(mat, U):
        s0 = mat.statistics(mat.mu0)
        out = []
        for mu, g in zip(mus, groups):
            lobe = bs.evolve(mat.lobe, s0, mat.statistics(mu), method=method, size=size, tol=tol)
            out.append(lobe.density(U[g]))
        return jnp.concatenate(out)

    Uj = jnp.asarray(U)
    values = run(mat, Uj)
    t = best_time(lambda: run(mat, Uj).block_until_ready(), repeat=repeat, budget=TIMING_BUDGET)
    return {"method": method, "size": size, "tol": tol, "seconds": t, "error": relative_error(values, ref, peak)}


def pareto(points):
    front, best = [], math.inf
    for p in sorted(points, key=lambda p: (p["seconds"], p["error"])):
        if p["error"] < best:
            front.append(p)
            best = p["error"]
    return front


TARGETS = [1e-3, 1e-4, 1e-6, 1e-8]
TIMING_BUDGET = 0.25  # seconds: sweep points and plans are timed for at least this long (best round kept)
RANKING_TARGET = 1e-6


def planner_points(materials, queries, factor, ref, peak, sweep, targets, repeat):
    """The planner at each error target: its path, time, error, predicted cost, and the ratio of
    its time to the fastest swept configuration at least as accurate."""
    out = []
    for target in targets:
        sc = scene.Scene(materials, queries, float(target))
        t0 = time.perf_counter()
        p = scene.plan(sc)
        plan_seconds = time.perf_counter() - t0
        values = np.asarray(p.evaluate()) / factor
        t = best_time(lambda: p.evaluate().block_until_ready(), repeat=repeat, budget=TIMING_BUDGET)
        err = relative_error(values, ref, peak)
        adequate = [q["seconds"] for q in sweep if q["error"] <= err]
        out.append(
            {
                "target": target,
                "error": err,
                "seconds": t,
                "plan_seconds": plan_seconds,
                "predicted_error": p.predicted_error,
                "predicted_cost_units": p.predicted_cost,
                "seconds_per_unit": t / p.predicted_cost,
                "path": p.parts[0].path,
                "details": p.parts[0].details,
                "pareto_seconds_at_error": min(adequate) if adequate else None,
                "ratio_to_pareto": t / min(adequate) if adequate else None,
                "explain": p.explain(),
            }
        )
    return out


def ranking(materials, queries, methods, target, repeat):
    """Every applicable path forced on one problem: the cost model's predicted ranking against
    the measured ranking (the ranking is what the planner relies on)."""
    forced = []
    for method in methods:
        p = scene.plan(scene.Scene(materials, queries, float(target)), method=method)
        t = best_time(lambda: p.evaluate().block_until_ready(), repeat=repeat, budget=TIMING_BUDGET)
        forced.append(
            {
                "method": method,
                "details": p.parts[0].details,
                "predicted_cost_units": p.predicted_cost,
                "seconds": t,
                "seconds_per_unit": t / p.predicted_cost,
            }
        )
    predicted = [f["method"] for f in sorted(forced, key=lambda f: f["predicted_cost_units"])]
    measured = [f["method"] for f in sorted(forced, key=lambda f: f["seconds"])]
    # pairs the model separates clearly (predicted costs ≥ 2× apart): is the cheaper one faster?
    clear = [(a, b) for a in forced for b in forced if b["predicted_cost_units"] >= 2 * a["predicted_cost_units"]]
    return {
        "target": target,
        "forced": forced,
        "predicted_order": predicted,
        "measured_order": measured,
        "order_matches": predicted == measured,
        "clear_pairs": len(clear),
        "clear_pairs_ordered_right": sum(a["seconds"] < b["seconds"] for a, b in clear),
    }


def bench_problem(kind, quick):
    started = time.perf_counter()
    mat = material(kind)
    mus = np.array([3e-3, 0.1]) if not quick else np.array([0.01])
    n = 7 if quick else 15
    U, M, d, ref, peak = problem_queries(kind, mus, n)
    F = np.asarray(microfacet_factor(jnp.asarray(d), jnp.asarray(d)))
    repeat = 2 if quick else 5
    closed = kind == "closed_form"
    isotropic = kind in ("closed_form", "beckmann_ggx", "disk", "plus")
    tols = [1e-8] if quick else [1e-4, 1e-7, 1e-10]
    knobs = []
    if closed:
        knobs.append(("closed_form", None, 1e-10))
    if isotropic:
        knobs += [("radial", n_, t) for n_ in ([64] if quick else [32, 64, 128, 256, 512]) for t in tols]
    knobs += [("grid", n_, t) for n_ in ([64] if quick else [64, 128, 256, 512]) for t in tols]
    points = []
    for method, size, tol in knobs:
        try:
            points.append(sweep_point(mat, kind, mus, U, ref, peak, method, size, tol, repeat))
        except bs.BrdfscaleError as err:  # e.g. a grid too coarse for the cut-off it was given
            points.append({"method": method, "size": size, "tol": tol, "failed": str(err)})
    ok = [p for p in points if "error" in p]
    queries = scene.Queries(d, d, M)
    planner = planner_points((mat,), queries, F, ref, peak, ok, [1e-4] if quick else TARGETS, repeat)
    methods = (["closed_form"] if closed else []) + (["radial"] if isotropic else []) + ["grid"]
    ranked = ranking((mat,), queries, methods, RANKING_TARGET, repeat) if len(methods) > 1 else None
    check = None
    if not quick and kind == "plus":
        import mpmath

        z = [0.5, 2.0, 5.0]
        exact = [float(mpmath.quad(lambda x: (mpmath.besselj(0, zz * x / PLUS_X0) - 1) / x, [0, PLUS_X0])) for zz in z]
        check = {"z": z, "series_H0": plus_h0(np.array(z)).tolist(), "mpmath_H0": exact}
    if not quick and kind in ("beckmann_ggx", "disk"):
        r = float(np.linalg.norm(U[3]))
        check = {
            "radius": r,
            "mu": float(mus[0]),
            "scipy": float(hankel_reference(kind, mus[0], [r])[0]),
            "mpmath": mpmath_check(kind, mus[0], r),
        }
    return {
        "problem": kind,
        "mus": mus.tolist(),
        "queries": len(U),
        "sweep": points,
        "pareto": pareto(ok),
        "planner": planner,
        "ranking": ranked,
        "reference_check": check,
        "wall_seconds": time.perf_counter() - started,
    }


def so3_sweep_point(mat, problem, ref, peak, B, repeat):
    """The public SO(3) pipeline at band limit B for all orders: lobe samples and
    :func:`so3.forward` at B, :func:`so3.evolve_diffusion` to each scale, :func:`so3.synthesize` —
    each the library's own jit-compiled call (one program fusing them all stalled the XLA CPU
    runtime at B = 64 in a trial run: no progress, no CPU use, waiting on a futex)."""
    pairs, angles, mus = problem["pairs"], problem["angles"], problem["mus"]

    def run(mat):
        tau0 = mat.tau(mat.mu0)
        out = []
        for (i, o), a in zip(pairs, angles):
            R0 = so3.forward(mat.lobe.samples(i, o, B))
            for mu in mus:
                R = so3.evolve_diffusion(R0, mat.law.D, tau0, mat.tau(mu))
                out.append(jnp.real(so3.synthesize(R, a[:, 0], a[:, 1], a[:, 2])))
        return jnp.concatenate(out)

    values = run(mat)
    t = best_time(lambda: run(mat).block_until_ready(), repeat=repeat, budget=TIMING_BUDGET)
    return {"method": "so3", "size": B, "tol": None, "seconds": t, "error": relative_error(values, ref, peak)}


def bench_so3_problem(quick):
    """SO(3) reference problem: an anisotropic Beckmann facet lobe (α = 0.3 along the tangent,
    0.15 along the bitangent) under isotropic rotational-diffusion statistics, two (i, o) pairs,
    global orientations with tilts and twists; reference: the group integral (so3_reference)."""
    started = time.perf_counter()
    mat = so3_material()
    mus = np.array([3e-3, 0.1]) if not quick else np.array([0.01])
    n = 6 if quick else 20
    repeat = 2 if quick else 3
    queries, ref, peak, problem = so3_problem(mus, n, nodes=32 if quick else 48)
    points = [
        so3_sweep_point(mat, problem, ref, peak, B, repeat) for B in ([16] if quick else [16, 24, 32, 40, 48, 64])
    ]
    planner = planner_points(
        (mat,), queries, np.ones(len(ref)), ref, peak, points, [1e-3] if quick else TARGETS[:3], repeat
    )
    check = None
    if not quick:  # convergence of the reference quadrature at one orientation per scale
        i, o = problem["pairs"][0]
        a = problem["angles"][0][:1]
        check = {
            "nodes": [48, 64],
            "values": [[float(so3_reference(mu, i, o, a, nodes)[0][0]) for nodes in (48, 64)] for mu in mus],
        }
    return {
        "problem": "so3",
        "mus": mus.tolist(),
        "queries": len(ref),
        "sweep": points,
        "pareto": pareto(points),
        "planner": planner,
        "ranking": None,
        "reference_check": check,
        "wall_seconds": time.perf_counter() - started,
    }


# -- workload ---------------------------------------------------------------------------------------
def checkerboard(points):
    return (np.floor(points[:, 0] / 0.5) + np.floor(points[:, 1] / 0.5)).astype(int) % 2


def workload_reference(sc):
    """Per-query lobe shape g and its peak g(0) at the query's own μ (SciPy / closed form)."""
    q = sc.queries
    from brdfscale.geometry import half_slope

    u = np.asarray(half_slope(q.i, q.o) - q.m_inf)
    mu = np.asarray(q.mu)
    index = np.asarray(q.material)
    g, peak = np.empty(len(mu)), np.empty(len(mu))
    for m, kind in enumerate(("beckmann_ggx", "closed_form")):
        rows = np.flatnonzero(index == m)
        for chunk in np.array_split(rows, max(1, len(rows) // 2048)):
            g[chunk] = [0.0] * len(chunk)
            if kind == "closed_form":
                var = (LOBE_ALPHA**2 + alpha(MU0) ** 2 - np.asarray(WIDTH(mu[chunk])) ** 2) / 2
                g[chunk] = np.exp(-np.sum(u[chunk] ** 2, -1) / (2 * var)) / (2 * np.pi * var)
                peak[chunk] = 1 / (2 * np.pi * var)
            else:
                g[chunk] = _hankel_rows(mu[chunk], np.linalg.norm(u[chunk], axis=-1))
                peak[chunk] = _hankel_rows(mu[chunk], np.zeros(len(chunk)))
    return g, peak


def bench_workload(resolution, naive_samples, tol):
    cam = scene.Camera(height=1.0, pitch=0.35, fov=0.7, resolution=(resolution, resolution))
    light = np.array([0.9, 0.0, 0.44])
    light /= np.linalg.norm(light)
    mats = (material("beckmann_ggx"), material("closed_form"))
    sc = scene.camera_scene(mats, cam, light, tol, texture=checkerboard)
    q = sc.queries
    F = np.asarray(microfacet_factor(q.i, q.o))
    t0 = time.perf_counter()
    p = scene.plan(sc)
    plan_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    values = np.asarray(p.evaluate().block_until_ready())
    first_seconds = time.perf_counter() - t0
    t_eval = best_time(lambda: p.evaluate().block_until_ready(), repeat=3)
    g, peak = workload_reference(sc)
    err_peak = np.abs(values / F - g) / peak
    strong = g > 1e-2 * peak
    err_point = np.abs(values[strong] / F[strong] - g[strong]) / g[strong]

    # naive: the grid path at each sampled pixel's own μ
    rng = np.random.default_rng(0)
    sample = rng.choice(len(q), size=naive_samples, replace=False)
    from brdfscale.geometry import half_slope

    u = np.asarray(half_slope(q.i, q.o) - q.m_inf)
    naive_times, naive_err, sizes = [], [], []
    for j in sample:
        mat = mats[int(q.material[j])]
        lobe = bs.evolve(mat.lobe, mat.statistics(mat.mu0), mat.statistics(q.mu[j]), method="grid", tol=tol)
        uj = jnp.asarray(u[j])
        value = float(lobe.density(uj))
        t = best_time(lambda: lobe.density(uj).block_until_ready(), repeat=2)
        naive_times.append(t)
        sizes.append(lobe.shape.size)
        naive_err.append(abs(value - g[j]) / peak[j])
    naive_seconds = float(np.mean(naive_times)) * len(q)
    image = np.asarray(p.image(jnp.asarray(values)))
    mu_image = np.zeros(resolution * resolution)
    mu_image[np.asarray(sc.pixels)] = np.asarray(q.mu)
    return (
        {
            "resolution": resolution,
            "queries": len(q),
            "tol": tol,
            "mu_min": float(q.mu.min()),
            "mu_max": float(q.mu.max()),
            "mu_ratio": float(q.mu.max() / q.mu.min()),
            "plan_seconds": plan_seconds,
            "first_evaluate_seconds_with_compile": first_seconds,
            "evaluate_seconds": t_eval,
            "predicted_cost_units": p.predicted_cost,
            "seconds_per_unit": t_eval / p.predicted_cost,
            "max_error_rel_peak": float(err_peak.max()),
            "predicted_error": p.predicted_error,
            "max_pointwise_rel_error_where_above_1pct_of_peak": float(err_point.max()),
            "naive_pixels_sampled": naive_samples,
            "naive_grid_sizes": sorted(set(int(s) for s in sizes)),
            "naive_seconds_per_pixel": float(np.mean(naive_times)),
            "naive_seconds_extrapolated": naive_seconds,
            "naive_max_error_rel_peak_on_sample": float(max(naive_err)),
            "speedup_evaluate_vs_naive": naive_seconds / t_eval,
            "speedup_plan_plus_evaluate_vs_naive": naive_seconds / (plan_seconds + first_seconds),
            "explain": p.explain(),
        },
        image,
        mu_image.reshape(resolution, resolution),
        err_peak,
        sc,
    )


def cost_model_summary(problems, work):
    """How well the cost model's relative units predict measured time: the forced-path rankings
    per problem, the rank correlation over every plan timed in this run, the seconds per unit."""
    from scipy.stats import spearmanr

    plans = [(pl["predicted_cost_units"], pl["seconds"]) for prob in problems for pl in prob["planner"]]
    plans += [
        (f["predicted_cost_units"], f["seconds"])
        for prob in problems
        if prob["ranking"]
        for f in prob["ranking"]["forced"]
    ]
    plans.append((work["predicted_cost_units"], work["evaluate_seconds"]))
    units, seconds = np.array(plans).T
    rankings = [prob["ranking"] for prob in problems if prob["ranking"]]
    per_unit = seconds / units
    return {
        "rankings": len(rankings),
        "rankings_matching": sum(r["order_matches"] for r in rankings),
        "clear_pairs": sum(r["clear_pairs"] for r in rankings),
        "clear_pairs_ordered_right": sum(r["clear_pairs_ordered_right"] for r in rankings),
        "plans": len(plans),
        "spearman": float(spearmanr(units, seconds).statistic) if len(plans) > 2 else None,
        "seconds_per_unit_min": float(per_unit.min()),
        "seconds_per_unit_max": float(per_unit.max()),
        "seconds_per_unit_median": float(np.median(per_unit)),
    }


def _save(fig, path) -> None:
    """``fig`` as PNG through brdfscale's checked write path (brdfscale.files.atomic_write)."""
    from brdfscale import files

    files.atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"), overwrite=True)


def plots(results, image, mu_image, suffix):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    problems = results["problems"]
    fig, axes = plt.subplots(1, len(problems), figsize=(4.2 * len(problems), 3.6), squeeze=False)
    colours = {"closed_form": "k", "radial": "tab:blue", "grid": "tab:orange", "so3": "tab:green"}
    for ax, prob in zip(axes[0], problems):
        for method, c in colours.items():
            pts = [p for p in prob["sweep"] if p.get("method") == method and "error" in p]
            if pts:
                ax.scatter(
                    [p["seconds"] for p in pts],
                    [max(p["error"], 1e-17) for p in pts],
                    s=12,
                    c=c,
                    label=method,
                    alpha=0.6,
                )
        front = prob["pareto"]
        ax.step([p["seconds"] for p in front], [max(p["error"], 1e-17) for p in front], where="post", c="grey", lw=1)
        for pl in prob["planner"]:
            ax.scatter(
                pl["seconds"],
                max(pl["error"], 1e-17),
                marker="*",
                s=120,
                c="red",
                label="planner" if pl is prob["planner"][0] else None,
            )
        ax.set(
            xscale="log",
            yscale="log",
            xlabel="time per evaluation [s]",
            ylabel="max error / peak",
            title=prob["problem"],
        )
        ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, RESULTS / f"bench_planner_pareto{suffix}.png")
    plt.close(fig)
    fig, axes = plt.subplots(1, 2, figsize=(9, 4))
    axes[0].imshow(np.log10(np.maximum(image, 1e-6 * image.max())), cmap="magma")
    axes[0].set_title("log10 ρ (planner)")
    im = axes[1].imshow(np.log10(np.where(mu_image > 0, mu_image, np.nan)), cmap="viridis")
    axes[1].set_title("log10 μ (pixel footprint)")
    fig.colorbar(im, ax=axes[1])
    for ax in axes:
        ax.axis("off")
    fig.tight_layout()
    _save(fig, RESULTS / f"bench_planner_workload{suffix}.png")
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sweep and a 48×48 image (smoke test)")
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--naive-samples", type=int, default=32)
    parser.add_argument("--no-plots", action="store_true")
    args = parser.parse_args(argv)
    quick = args.quick
    kinds = ["closed_form", "beckmann_ggx", "skewed_mixture", "disk", "plus"]
    load_before = os.getloadavg()
    # the workload first, in a fresh process: its planning time includes every compilation a
    # user's first plan of a scene pays (the reference problems below would warm them up)
    work, image, mu_image, _, _ = bench_workload(
        24 if quick else args.resolution, 1 if quick else args.naive_samples, 1e-4
    )
    problems = []
    for kind in kinds + ["so3"]:
        problems.append(bench_so3_problem(quick) if kind == "so3" else bench_problem(kind, quick))
        print(f"{kind}: {problems[-1]['wall_seconds']:.0f} s", flush=True)
    for prob in problems:
        for pl in prob["planner"]:
            ratio = pl["ratio_to_pareto"]
            pareto_text = (
                "none as accurate"
                if ratio is None
                else f"{pl['pareto_seconds_at_error'] * 1e3:8.3f} ms, ratio {ratio:.2f}"
            )
            print(
                f"{prob['problem']:>15} target {pl['target']:.0e}: {pl['path']:>11} error {pl['error']:.2e} "
                f"time {pl['seconds'] * 1e3:8.3f} ms; Pareto time at that error {pareto_text}"
            )
    print(
        f"workload {work['resolution']}²: μ ratio {work['mu_ratio']:.0f}; planner "
        f"{work['evaluate_seconds'] * 1e3:.1f} ms "
        f"(plan {work['plan_seconds']:.1f} s), max error {work['max_error_rel_peak']:.2e}; naive "
        f"{work['naive_seconds_extrapolated']:.1f} s (extrapolated), speedup {work['speedup_evaluate_vs_naive']:.0f}×"
    )
    cost_model = cost_model_summary(problems, work)
    print(
        f"cost model: predicted order of forced paths matches the measured order on "
        f"{cost_model['rankings_matching']}/{cost_model['rankings']} problems (pairs ≥ 2× apart in prediction "
        f"ordered right: {cost_model['clear_pairs_ordered_right']}/{cost_model['clear_pairs']}); "
        "Spearman ρ(predicted units, "
        f"measured s) over {cost_model['plans']} plans = {cost_model['spearman']:.2f}; seconds per unit "
        f"{cost_model['seconds_per_unit_min']:.2g}–{cost_model['seconds_per_unit_max']:.2g}"
    )
    results = {
        "benchmark": "bench_planner",
        "machine": machine(),
        "dtype": "float64",
        "quick": quick,
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "problems": problems,
        "workload": work,
        "cost_model": cost_model,
    }
    name = "bench_planner_quick" if quick else "bench_planner"
    path = write_json(name, results)
    if not args.no_plots:
        plots(results, image, mu_image, "_quick" if quick else "")
    print(f"wrote {path}")
    return results


if __name__ == "__main__":
    main()
