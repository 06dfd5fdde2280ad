"""The tables of docs/results.md, from the studies' JSON files (experiments/results/<study>/).

``python -m experiments.benchmarks_page`` writes them into the page's generated blocks, with
the benchmarks' tables.
"""

import json
from pathlib import Path

from experiments._bench import RESULTS, table


def load(study: str, name: str) -> dict:
    return json.loads((RESULTS / study / f"{name}.json").read_text())


def consistency() -> str:
    d = load("consistency", "consistency")
    scales = d["scales_px"]
    out = [
        (
            f"Field {d['size']}² px, seed {d['seed']}. Entries: violation V / permutation floor "
            "(V ≈ floor: consistent within sampling noise); `*`: fewer than 10 % of the facets off the "
            "lattice origin (the test has lost its resolution there)."
        )
    ]
    for window in d["windows"]:
        rows = []
        for name in d["surfaces"]:
            cells = []
            for mu in scales:
                r = next(r for r in d["records"] if r["surface"] == name and r["window"] == window and r["mu_px"] == mu)
                flag = "*" if r["facet_slopes_off_lattice_origin"] < 0.1 else ""
                cells.append(f"{r['violation']:.3f} / {r['floor']:.3f}{flag}")
            rows.append([name, *cells])
        out.append(f"\n**{window} window**\n\n" + table(["surface", *[f"μ = {m}" for m in scales]], rows))
    rows = []
    for name in d["surfaces"]:
        for mu in (4, 16):
            r = next(
                (r for r in d["records"] if r["surface"] == name and r["window"] == "gaussian" and r["mu_px"] == mu),
                None,
            )
            if r is not None:
                cross = r["total_variance"] - r["within_variance"] - r["between_variance"]
                rows.append(
                    [
                        name,
                        str(mu),
                        f"{r['within_variance']:.3g}",
                        f"{r['between_variance']:.3g}",
                        f"{cross / r['total_variance']:+.3f}",
                    ]
                )
    out.append(
        "\n**Second moments, Gaussian window** (box windows: cross term 0 by construction)\n\n"
        + table(["surface", "μ", "Var r (within)", "Var M (between)", "cross term / Var m"], rows)
    )
    return "\n".join(out)


def evolution() -> str:
    d = load("evolution_accuracy", "evolution_accuracy")
    cs = d["lambda_factors"]
    ev = [f"evolved_c{c:g}" for c in cs]
    header = [
        "surface / direction",
        "naive",
        "second moment",
        *[f"evolved c={c:g}" for c in cs],
        *[f"median E_ev/E_2nd (c={c:g})" for c in cs],
        *[f"pairs with E_ev ≤ ½ E_2nd (c={c:g})" for c in cs],
    ]
    rows = []
    for key, s in d["summary"].items():
        rows.append(
            [
                key,
                f"{s['median_error_naive']:.3f}",
                f"{s['median_error_second_moment']:.3f}",
                *[f"{s[f'median_error_{e}']:.3f}" for e in ev],
                *[f"{s[f'median_ratio_{e}_to_second_moment']:.2f}" for e in ev],
                *[f"{s[f'pairs_{e}_meeting_target_ratio_le_0.5']}/{s['pairs']}" for e in ev],
            ]
        )
    out = [
        (
            f"Field {d['size']}² px, scales {d['scales_px']} px and ∞, {d['bins']}² nodes, resolution "
            f"σ_r = {d['resolution_nodes']:g} nodes. Median L1 error over the pairs of each direction:\n"
        ),
        table(header, rows),
    ]
    rows = []
    for r in d["records"]:
        if r["surface"] in ("scratched", "blazed"):
            rows.append(
                [
                    r["surface"],
                    f"{r['mu_from']}→{r['mu_to']}",
                    f"{r['error_naive']:.3f}",
                    f"{r['error_second_moment']:.3f}",
                    *[f"{r[f'error_{e}']:.3f}" for e in ev],
                    *[f"{r[f'lambda_{e}']:.3g}" for e in ev],
                ]
            )
    out.append(
        "\n**Non-Gaussian surfaces, every pair** (λ: the regularisation evolve accepted)\n\n"
        + table(
            [
                "surface",
                "μ0→μ",
                "naive",
                "second moment",
                *[f"evolved c={c:g}" for c in cs],
                *[f"λ (c={c:g})" for c in cs],
            ],
            rows,
        )
    )
    return "\n".join(out)


def validity() -> str:
    d = load("validity", "validity")
    thetas = d["theta_i_deg"]
    out = [
        (
            f"Field {d['size']}² px, correlation length {d['correlation_length_px']:g} px. Entries: E without "
            "masking / E with shadowing+masking / albedo ratio model ÷ brute (masked)."
        )
    ]
    rows = []
    for s in d["rms_slopes_per_axis"]:
        cells = []
        for t in thetas:
            r = next(r for r in d["records"] if r["rms_slope_per_axis"] == s and r["theta_i_deg"] == t)
            cells.append(
                f"{r['error_vs_brute']:.3f} / {r['error_vs_brute_masked']:.3f} / "
                f"{r['albedo_ratio_vs_brute_masked']:.2f}"
            )
        rows.append([f"{s:g}", *cells])
    out.append(table(["rms slope", *[f"θi = {t:g}°" for t in thetas]], rows))
    return "\n".join(out)


def render() -> str:
    out = []
    for path in sorted((RESULTS / "render_plane").glob("*.json")):
        d = json.loads(path.read_text())
        bands = [b["mu_band_px"][0] for b in d["errors"]["naive"]["bands"]]
        rows = []
        for m, e in d["errors"].items():
            rows.append(
                [
                    m,
                    f"{e['relative_mean_abs']:.3f}",
                    f"{e['relative_rms']:.2f}",
                    *[f"{b['relative_bias']:.3f}" for b in e["bands"]],
                ]
            )
        lam = ", ".join(f"{lv['level_px']}: {lv['lambda']:.3g}" for lv in d["levels"])
        out.append(
            f"**{d['surface']}** (heights × {d['slope_scale']:g}, α0 = {d['alpha0']:g}, image "
            f"{d['image'][0]}×{d['image'][1]}, texture {d['texture_size']}², μ from {d['mu_range_px'][0]:.2f} "
            f"to {d['mu_range_px'][1]:.1f} texels; λ per level {lam})\n\n"
            + table(["method", "mean abs error", "RMS error", *[f"bias μ∈[{b:g},{2 * b:g})" for b in bands]], rows)
        )
    return "\n\n".join(out)


def _param_text(params: dict) -> str:
    return ", ".join(
        f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
        for k, v in params.items()
        if k not in ("alpha_from", "alpha_to", "alpha_lobe", "x0", "honoured_tol")
    )


def stability() -> str:
    d = load("stability", "stability")
    s = d["summary"]
    t = s["totals"]
    out = [
        (
            f"{t['tried']} cases: {t['good']} good (accurate, or refused with the library's error where no result "
            f"exists), {t['limit']} at a documented limit, {t['bad']} bad; NaN {t['nan']}, Inf {t['inf']} in the "
            f"returned values; non-finite results on valid input: {t['nonfinite_on_valid_input']} (target 0 — "
            f"{'met' if t['nonfinite_on_valid_input'] == 0 else '**not met**'}). Evolution targets: tol "
            f"{d['evolve_tol']['float64']:g} (float64), {d['float32_target']:g} of the peak (float32).\n"
        )
    ]
    rows = []
    for p in s["by_path"]:
        where = "; ".join(
            f"{_param_text(f['params'])}: {f['status']}" + ("" if f["error"] is None else f" ({f['error']:.1e})")
            for f in p["failing"][:4]
        )
        if len(p["failing"]) > 4:
            where += f"; … ({len(p['failing'])} in all)"
        rows.append(
            [
                p["kind"],
                p["path"],
                p["dtype"],
                str(p["tried"]),
                str(p["good"]),
                str(p["limit"]),
                str(p["bad"]),
                str(p["nan"]),
                str(p["inf"]),
                "–" if p["max_error"] is None else f"{p['max_error']:.1e}",
                where or "–",
            ]
        )
    out.append(
        table(
            [
                "kind",
                "path",
                "dtype",
                "tried",
                "good",
                "limit",
                "bad",
                "NaN",
                "Inf",
                "largest error (accurate)",
                "not accurate at",
            ],
            rows,
        )
    )
    n = d.get("noise")
    if n:
        rules = list(n["summary"])
        rows = []
        keys = list(dict.fromkeys((r["case"], r["counts_at_peak"]) for r in n["runs"]))
        for case, count in keys:
            runs = [r for r in n["runs"] if r["case"] == case and r["counts_at_peak"] == count]
            best = sorted(r["best_fixed_error"] for r in runs)[len(runs) // 2]
            cells = []
            for rule in rules:
                ratios = [r["rules"][rule]["ratio_to_best_fixed"] for r in runs]
                lam = runs[0]["rules"][rule]["lambda"]
                cells.append(f"{max(ratios):.2f} (λ {lam:.2g})")
            rows.append(
                [
                    case,
                    f"{count:.0e}",
                    f"{1 / count**0.5:.2g}",
                    f"{best:.3f}",
                    f"{runs[0]['best_fixed_lambda']:.2g}",
                    *cells,
                ]
            )
        seeds = len({r["seed"] for r in n["runs"]})
        out.append(
            f"\n**Coarse → fine under noise** ({n['nodes']}² nodes, Poisson noise, {seeds} seed(s) per level; error: "
            f"{n['error']}; entries: the largest ratio over the seeds of a rule's error to the best fixed λ's, "
            "and the λ it chose for seed 0)\n"
        )
        out.append(
            table(
                [
                    "case",
                    "counts at peak",
                    "noise at peak",
                    "best fixed λ error (median)",
                    "best fixed λ (seed 0)",
                    *[f"{r} ratio" for r in rules],
                ],
                rows,
            )
        )
        summary = "; ".join(
            f"{r}: largest ratio {v['max_ratio']:.2f}, median {v['median_ratio']:.2f}, "
            f"{v['runs_within_2']}/{v['runs']} runs within 2×"
            for r, v in n["summary"].items()
        )
        out.append(
            f"\n{summary}. Default rule `{n['default_rule']}`; target ({n['target']}): "
            f"{'met' if n['target_met'] else '**not met**'}."
        )
    return "\n".join(out)


def stability_figures(directory: Path | None = None) -> list:
    """Redraw the stability study's figures from its committed JSON (into ``directory``,
    default the study's folder): ``python -m experiments.benchmarks_page`` does it with the
    tables, and tests/test_experiments_smoke.py checks the committed PNGs are what the JSON gives."""
    from experiments import stability

    return stability.plot(load("stability", "stability"), directory or RESULTS / "stability")


LAW_PARAMETERS = {
    "rms_height_m": "σ_h [m]",
    "correlation_length_m": "ℓ [m]",
    "correlation_length_x_m": "ℓ_x [m]",
    "correlation_length_y_m": "ℓ_y [m]",
    "A_m4": "A [m⁴]",
    "B_m": "B [m]",
    "C": "C",
    "k_max_per_m": "k_max [1/m]",
}


def real_surfaces() -> str:
    """Study 6 (experiments/real_surfaces.py): the seed's equations on the measured surfaces."""
    d = load("real_surfaces", "real_surfaces")
    surfaces = d["surfaces"]
    primary = f"evolved_c{d['primary_lambda_factor']:g}"
    cs = d["lambda_factors"]
    out = [
        (
            f"{len(surfaces)} files, {d['detrend']} removed; lobes on {d['bins']}² nodes (grids: {d['grids']}), "
            f"L1 error after a resolution of σ_r = {d['resolution_nodes']:g} nodes; λ rule: {d['lambda_rule']} "
            f"(c = {', '.join(f'{c:g}' for c in cs)}; c = {d['primary_lambda_factor']:g} primary). Largest scale: "
            f"the largest window leaving {d['min_facets_at_largest_scale']} measured facets. Non-Gaussian: "
            f"{d['non_gaussian_rule']}. Run time {d['seconds']:.0f} s.\n"
        )
    ]

    rows = []
    for s in surfaces:
        m, sh = s["pixel_slopes"], s["shadowing"]
        rows.append(
            [
                f"`{s['file']}`",
                f"{s['shape'][0]}×{s['shape'][1]}",
                f"{s['pixel_m'] * 1e6:.4g} µm",
                str(s["unmeasured_px"]),
                f"{m['x']['sd']:.3g}, {m['y']['sd']:.3g}",
                f"{m['x']['robust_sd']:.3g}, {m['y']['robust_sd']:.3g}",
                f"{m['x']['skewness']:+.2f}, {m['y']['skewness']:+.2f}",
                f"{m['x']['excess_kurtosis']:.3g}, {m['y']['excess_kurtosis']:.3g}",
                "no" if s["non_gaussian"] else "yes",
                "–"
                if s["height_quantum_m"] is None
                else f"{s['height_quantum_m'] * 1e9:.3g} nm ({s['slope_quantum_to_robust_sd']:.2f})",
                f"{sh['theta_deg_shadowing_1pct']:g}° / {sh['theta_deg_shadowing_10pct']:g}°",
            ]
        )
    out.append(
        "**The surfaces** (pixel slopes of the measured pixel facets; shadowing: Smith's Λ/(1+Λ) from the "
        "measured slopes, worst of ±x, ±y, exceeds 1 % / 10 % beyond θi)\n\n"
        + table(
            [
                "file",
                "pixels (rows×cols)",
                "pixel",
                "unmeasured px",
                "rms slope x, y",
                "robust sd x, y",
                "skewness x, y",
                "excess kurtosis x, y",
                "Gaussian",
                "height quantum (÷Δ ÷ robust sd)",
                "shadowing > 1 % / 10 %",
            ],
            rows,
        )
    )

    rows = []
    for s in surfaces:
        for r in s["sigma"]:
            cov, err = r["covariance"], r["covariance_error_used"]
            z = r["split_half_z"]
            kurt = r["facet_excess_kurtosis"]
            rows.append(
                [
                    f"`{s['file']}`",
                    str(r["mu_px"]),
                    f"{r['mu'] * 1e6:.4g}",
                    f"{r['count']} ({r['independent']:.1f})",
                    f"{cov[0][0]:.3g} ± {err[0][0]:.2g}",
                    f"{cov[1][1]:.3g} ± {err[1][1]:.2g}",
                    f"{cov[0][1] / (cov[0][0] * cov[1][1]) ** 0.5:+.2f}",
                    "–" if z is None else f"{z[0]:+.1f}, {z[1]:+.1f}",
                    f"{r['trace_ratio_curvature_to_plane']:.3f}",
                    "–" if kurt[0] is None else f"{kurt[0]:.3g}, {kurt[1]:.3g}",
                ]
            )
    out.append(
        "\n**Σ(μ)** (facets: count (effective independent); ± the standard error used in the fits: the "
        "library's, floored at the Gaussian-theory error from N_eff; z: the two halves' Σ_xx, Σ_yy differ "
        "by z standard errors; curvature/plane: tr Σ with a quadratic removed ÷ with a plane removed)\n\n"
        + table(
            [
                "file",
                "μ [px]",
                "μ [µm]",
                "facets",
                "Σ_xx",
                "Σ_yy",
                "ρ_xy",
                "split-half z (xx, yy)",
                "curvature/plane",
                "facet excess kurtosis x, y",
            ],
            rows,
        )
    )

    rows = []
    for s in surfaces:
        for law, fit in s["laws"].items():
            if law == "measured_rms_height_m":
                continue
            if fit is None:
                rows.append([f"`{s['file']}`", law, "no fit", "–", "–", "–"])
                continue
            p = fit["parameters"]
            text = ", ".join(f"{LAW_PARAMETERS.get(k, k)} = {v:.3g}" for k, v in p.items())
            rows.append(
                [
                    f"`{s['file']}`",
                    law,
                    text,
                    f"{fit['chi2_per_dof']:.3g}",
                    f"{fit['relative_rms_diagonal']:.2f}",
                    f"{fit['largest_relative_deviation']:.2f}",
                ]
            )
    out.append(
        "\n**Scale laws fitted to Σ(μ)** (GaussianSurface, box window; χ² over Σ_xx, Σ_yy, Σ_xy at every "
        "scale in the standard errors above; relative deviations of the diagonal)\n\n"
        + table(["file", "law", "parameters", "χ²/dof", "relative rms", "largest relative deviation"], rows)
    )

    rows = []
    for s in surfaces:
        cells = []
        for r in s["consistency"]:
            flag = "*" if r["facet_slopes_off_lattice_origin"] < 0.1 else ""
            cells.append(f"{r['mu_px']}: {r['violation']:.3f} / {r['floor']:.3f}{flag}")
        quantum = [
            f"{r['mu_px']}: {q['violation']:.3f} / {q['floor']:.3f}"
            + ("*" if q["facet_slopes_off_lattice_origin"] < 0.1 else "")
            for r in s["consistency"]
            if (q := r.get("at_slope_quantum"))
        ]
        rows.append(
            [
                f"`{s['file']}`",
                f"{s['lattice_step']:.3g}",
                "; ".join(cells),
                f"{s['slope_quantum']:.3g}: " + "; ".join(quantum) if quantum else "–",
            ]
        )
    out.append(
        "\n**Eq. 3.1** (μ [px]: violation V / permutation floor; `*`: fewer than 10 % of the facets off the "
        "lattice origin, no resolution; last column: on a lattice of one slope quantum, where it is coarser)\n\n"
        + table(["file", "lattice step", "V / floor per scale", "on the slope quantum's lattice"], rows)
    )

    rows = []
    for key, e in d["summary"]["by_surface"].items():

        def med(k):
            v = e[f"median_error_{k}"]
            return "–" if v is None else f"{v:.3f}"

        rows.append(
            [
                key,
                str(e["pairs"]),
                med("naive"),
                med("second_moment"),
                *[med(f"evolved_c{c:g}") for c in cs],
                *[
                    f"{e[f'median_ratio_evolved_c{c:g}']:.2f}" if e[f"median_ratio_evolved_c{c:g}"] is not None else "–"
                    for c in cs
                ],
                *[f"{e[f'pairs_meeting_evolved_c{c:g}']}/{e[f'pairs_with_lobe_evolved_c{c:g}']}" for c in cs],
                f"{e['pairs_meeting_on_both_halves']}/{e['pairs_with_both_halves']}",
                f"{e['pairs_evolved_beats_naive']}/{e['pairs']}",
                f"{e['pairs_evolved_within_floor']}/{e['pairs']}",
                "–" if e["median_split_half_sigma_evolved"] is None else f"{e['median_split_half_sigma_evolved']:.2g}",
            ]
        )
    out.append(
        "\n**Eq. 4.4: median L1 error of the predicted lobe** (ordered pairs of the lobe scales and ∞; "
        f"E_ev ≤ ½ E_2nd: pairs meeting the target / pairs with a lobe; halves: c = {d['primary_lambda_factor']:g} "
        "on both halves; floor: the split-half reproducibility of the measured target lobe; σ: split-half "
        "standard error of E_ev)\n\n"
        + table(
            [
                "surface / direction",
                "pairs",
                "naive",
                "second moment",
                *[f"evolved c={c:g}" for c in cs],
                *[f"median E_ev/E_2nd (c={c:g})" for c in cs],
                *[f"E_ev ≤ ½ E_2nd (c={c:g})" for c in cs],
                "… on both halves",
                "E_ev < E_naive",
                "E_ev ≤ floor",
                "median σ(E_ev)",
            ],
            rows,
        )
    )

    for s in surfaces:
        names = [str(p) for p in s["lobe_scales_px"]] + ["∞"]
        cells = {(r["mu_from_px"], r["mu_to_px"]): r for r in s["records"]}
        rows = []
        for a in names:
            row = [a]
            for b in names:
                r = cells.get((a, b))
                if r is None:
                    row.append("–")
                    continue
                ev = r[f"error_{primary}"]
                sig = (
                    r["split_half_sigma"][primary]
                    if r["split_half_sigma"] and r["split_half_sigma"][primary] is not None
                    else None
                )
                mark = " ✓" if ev is not None and ev <= 0.5 * r["error_second_moment"] else ""
                evt = "no lobe" if ev is None else f"{ev:.3f}" + ("" if sig is None else f" ± {sig:.1g}")
                row.append(f"{evt} / {r['error_second_moment']:.3f} / {r['error_naive']:.3f}{mark}")
            rows.append(row)
        facets = {r["mu_from_px"]: (r["facets_from"], r["independent_from"]) for r in s["records"] if r["facets_from"]}
        counts = ", ".join(f"{p}: {facets[p][0]} ({facets[p][1]:.1f})" for p in names if p in facets)
        out.append(
            f"\n**`{s['file']}`, every pair** (rows μ0, columns μ [px]; E_ev ± σ / E_2nd / E_naive; ✓: "
            f"E_ev ≤ ½ E_2nd; facets (independent) per scale {counts})\n\n" + table(["μ0 \\ μ", *names], rows)
        )

    t = d["summary"]["target"]

    def frac(x):
        return "–" if x is None or x["fraction"] is None else f"{x['met']}/{x['pairs']} ({x['fraction']:.0%})"

    out.append(
        f"\n**Target** ({t['statement']}; non-Gaussian: {', '.join(t['non_gaussian_surfaces'])}): "
        f"{'met' if t['met'] else '**not met**'} — all pairs {frac(t['all_pairs'])}, coarser {frac(t['coarser'])}, "
        f"finer {frac(t['finer'])}; without the 1 px ↔ ∞ pairs {frac(t['without_harvey_pairs'])}; without those "
        f"and pairs with a scale of fewer than {d['few_facets']} independent facets "
        f"{frac(t['without_harvey_and_few_facet_pairs'])}; on both halves {frac(t['on_both_halves'])}"
        + (f"; c = 3 {frac(t['c3_all_pairs'])}" if t.get("c3_all_pairs") else "")
        + "."
    )
    return "\n".join(out)


def instrument() -> str:
    """Study 7 (experiments/instrument_study.py): the seed-only and masking-aware models against the ray tracer."""
    if not (RESULTS / "instrument" / "instrument_study.json").exists():
        return "(instrument_study.json missing: run the study)"
    d = load("instrument", "instrument_study")
    c, s = d["config"], d["summary"]
    lo, most = min(c["bounces"]), max(c["bounces"])
    load_avg = d.get("load_average", {})
    timing = d.get("seconds_ray_tracing", {})
    out = [
        (
            f"Ray-traced instrument: {c['rays']:,} rays per image, bounces {c['bounces']}, {c['pixels']}² px images, "
            f"synthetic fields {c['size']}² px (spot {sorted({m for v in c['scales_px'].values() for m in v})} px: the "
            "whole periodic field), the five real files at half the shorter side (less where a file has unmeasured "
            f"regions), each on both meshes; seed {c['seed']}; run time {d['seconds']:.0f} s, of which ray tracing "
            f"{sum(timing.values()):.0f} s (load average {load_avg.get('before', ['?'])[0]:.1f} before, "
            f"{load_avg.get('after', ['?'])[0]:.1f} after, 2 cores shared); largest MC error of an image's energy "
            f"{s['max_mc_energy']:.2%}. Entries at each surface's largest scale: energy ratio model ÷ instrument of "
            f"the seed's model / the masking-aware model (× Smith's height-correlated G₂) / the same with the "
            f"multiply scattered light (`smith_ms`, × G₂/E(i)) against the instrument with {most} bounces, in "
            "brackets the masking-aware model ÷ the single-scattering instrument.\n"
        )
    ]
    largest = {}
    for r in d["records"]:
        key = (r["surface"], r["mesh"])
        largest[key] = max(largest.get(key, 0.0), r["mu"])
    top = {
        (r["surface"], r["mesh"], r["theta_i_deg"]): r
        for r in d["records"]
        if r["mu"] == largest[(r["surface"], r["mesh"])]
    }
    thetas = sorted({r["theta_i_deg"] for r in d["records"]})
    meshes = list(dict.fromkeys(r["mesh"] for r in d["records"]))
    rows = []
    for mesh in meshes:
        for label, info in d["surfaces"].items():
            cells = []
            for t in thetas:
                r = top.get((label, mesh, t))
                if r is None:
                    cells.append("–")
                    continue
                e = {
                    k: r[f"{k}_bounces{most}"]["energy_ratio"]
                    for k in ("seed", "masking", "masking_ms")
                    if k + f"_bounces{most}" in r
                }
                cells.append(
                    " / ".join(f"{x:.3f}" for x in e.values()) + f" ({r[f'masking_bounces{lo}']['energy_ratio']:.3f})"
                )
            if any(x != "–" for x in cells):
                rows.append([f"{label} (rms slope {info['rms_slope']:.3g})", mesh.replace("_", " "), *cells])
    out.append(table(["surface", "mesh", *[f"θi = {t:g}°" for t in thetas]], rows))

    rows = []
    for label in d["surfaces"]:
        cells = []
        for t in thetas:
            tri, pix = top.get((label, "triangles", t)), top.get((label, "pixel_facets", t))
            if tri is None:
                cells.append("–")
                continue
            inter = tri["effects"]["interreflection"]
            smith = tri[f"masking_bounces{lo}"]["energy_ratio"] - 1
            walls = "" if pix is None else f" W {pix[f'masking_bounces{lo}']['energy_ratio'] - 1 - smith:+.1%}"
            cells.append(f"I {inter:+.1%} S {smith:+.1%}{walls}")
        if any(x != "–" for x in cells):
            rows.append([label, *cells])
    if rows:
        out.append(
            "\n**Why: the error budget** at the largest scale, in energy relative to the single-scattering "
            f"instrument: I — interreflection (the triangulated mesh's instrument with {most} bounces ÷ with 1, − 1); "
            "S — what Smith's G₂ misses of single scattering on the triangulated mesh (masking-aware ÷ instrument, "
            "− 1); W — the pixel-facet mesh's vertical slivers (its S less the triangulated mesh's). The "
            "masking-aware model against the full instrument is off by about S − I.\n\n"
            + table(["surface", *[f"θi = {t:g}°" for t in thetas]], rows)
        )

    rows = []
    names = [n for n in next(iter(s["targets"].values()))]
    for key, per in s["targets"].items():
        mesh, b = key.rsplit("_bounces", 1)
        for name in names:
            t = per[name]
            rows.append(
                [
                    mesh.replace("_", " "),
                    b,
                    name.replace("_", " "),
                    f"{t['within']} / {t['rows']}",
                    f"{t['within_where_seed_off']} / {t['seed_off']}",
                    "met" if t["met"] else "not met",
                ]
            )
    out.append(
        f"\n**The benchmark target** ({s['target_statement']}), per mesh and per truth (the instrument with 1 "
        f"bounce or {most}):\n\n"
        + table(
            ["mesh", "bounces", "model", "within 2 % (all rows)", "within where the seed is off > 10 %", "target"], rows
        )
    )

    if d.get("nearly_flat"):
        rows = [
            [
                f"{r['rms_slope']:g}",
                f"{r['theta_i_deg']:g}°",
                f"{r['alpha_eff']:.3f}",
                f"{r['seed']['second_moment_ratio']:.4f}",
                f"{r['masking']['second_moment_ratio']:.4f} ± {r['mc_second_moment']:.4f}",
                f"{r['masking']['energy_ratio']:.4f} ± {r['masking']['mc_energy']:.4f}",
                f"{r['masking_second_moment_error_over_alpha_geo2']:+.3f}",
            ]
            for r in d["nearly_flat"]
        ]
        out.append(
            f"\n**The nearly-flat term** (Gaussian fields with Beckmann micro-facets of α = {c['micro_alpha']:g}, the "
            f"triangulated mesh, single scattering, {c['nearly_flat_rays']:,} rays, the whole field; second moment "
            "Σ|u − ū|²g and energy of the model ÷ the instrument's, ± its MC error; the last column: the "
            "masking-aware model's second-moment error ÷ α_geo²)\n\n"
            + table(
                [
                    "α_geo (rms slope)",
                    "θi",
                    "√(second moment)",
                    "seed",
                    "masking-aware",
                    "energy (masking-aware)",
                    "error ÷ α_geo²",
                ],
                rows,
            )
        )

    rows = []
    for label, m in s["medians"].items():
        rows.append([label, *[f"{m[k]['median_l1']:.3f} / {m[k]['median_abs_energy_error']:.3f}" for k in m]])
    names = list(next(iter(s["medians"].values())))
    out.append(
        f"\n**Median over scales and incidences** ({meshes[0].replace('_', ' ')}, bounces {most}; relative L1 error "
        "/ |energy ratio − 1|)\n\n" + table(["surface", *[n.replace("_", " ") for n in names]], rows)
    )
    if d["evolution"]:
        e = s["evolution"]

        def fmt(x):
            return "–" if x is None else f"{x:.3f}"

        evo_thetas = list(dict.fromkeys(x["theta_i_deg"] for x in d["evolution"]))
        out.append(
            "\n**The evolution scored on instrument data** (pixel facets, the most bounces; median L1 over "
            f"{len(d['evolution'])} ordered pairs of scales, coarser and finer, on "
            f"{len({x['surface'] for x in d['evolution']})} surfaces; facets: the same pairs on the facet statistics)"
            "\n\n"
            + table(
                ["data", "θi", "naive", "second moment", "evolved (c = 1)"],
                [
                    [
                        data,
                        f"{t:g}°",
                        *[fmt(e.get(f"{data}_{n}_median_l1_at_{t:g}")) for n in ("naive", "second_moment", "evolved")],
                    ]
                    for t in evo_thetas
                    for data in ("instrument", "facets")
                ],
            )
        )
    if d.get("fits"):
        rows = []
        for f in d["fits"]:
            cells = []
            for fit in f["fits"]:
                if fit.get("amplitude") is None:
                    cells += [f"exit {fit['exit_status']}", "–", "–"]
                    continue
                cells += [f"{fit['amplitude']:.3f}", f"{fit['reduced_chi2']:.3g}", str(fit["outcome"])]
            rows.append([f["surface"], f"{f['theta_i_deg']:g}°", f"{f['instrument_energy_in_grid']:.3f}", *cells])
        model = next((fit["model"] for f in d["fits"] for fit in f["fits"] if fit.get("model")), "?")
        out.append(
            f"\n**The fits on instrument data** (`brdfscale fit --steps 0`: the default model, {model}; amplitude, "
            "χ²/dof and outcome without / with `--masking smith`; the amplitude's truth: the instrument's energy in "
            "the image grid)\n\n"
            + table(
                [
                    "surface",
                    "θi",
                    "energy in grid",
                    "A (none)",
                    "χ²/dof (none)",
                    "outcome (none)",
                    "A (smith)",
                    "χ²/dof (smith)",
                    "outcome (smith)",
                ],
                rows,
            )
        )
    return "\n".join(out)


MASKING_NAMES = {
    "closed": "brdfscale (closed form, masking of the slopes within the footprint)",
    "footprint_masking": "the same lobes tabulated, the same masking (control)",
    "all_scale_masking": "the same tables, masking of every scale's slopes",
    "no_masking": "the closed form without masking",
}


def far_signed_rows(record: dict, names: dict | None = None) -> tuple[list, list[list[str]]]:
    """A study 8 diagnosis' record (experiments.render_validation.diagnosis_record): the μ bands ≥ 8 and per
    material a row — its name (``names`` maps it), the signed band biases against the truth / the truth without shadow
    rays, their mean |·| (its ``far_bias``)."""
    first = next(iter(record["signed_bias"].values()))
    bands = [x["mu_band_px"] for x in first if x["mu_band_px"][0] >= 8]
    rows = []
    for name, signed in record["signed_bias"].items():
        mean = record["far_bias"][name]
        rows.append(
            [
                (names or {}).get(name, name),
                *[f"{x['truth']:+.3f} / {x['without_shadow_rays']:+.3f}" for x in signed if x["mu_band_px"][0] >= 8],
                f"{mean['truth']:.3f} / {mean['without_shadow_rays']:.3f}",
            ]
        )
    return bands, rows


def masking_diagnosis() -> list[str]:
    """experiments/render_masking.py: study 8's brdfscale material with its masking changed, per surface the signed
    band bias where μ ≥ 8 and its mean |·| (the ratio to LEAN's from the study's own JSON)."""
    path = RESULTS / "render_masking" / "masking.json"
    if not path.exists():
        return []
    d = json.loads(path.read_text())
    out = []
    for surface, record in d["surfaces"].items():
        study = RESULTS / "render_validation" / f"{surface}.json"
        lean = None
        if study.exists():
            lean = json.loads(study.read_text())["errors"]["lean"]["mu_ge_threshold"]["bias_mean_over_bands"]
        bands, rows = far_signed_rows(record, MASKING_NAMES)
        for row, mean in zip(rows, record["far_bias"].values()):
            row.append("—" if lean is None else f"{mean['truth'] / lean:.2f}")
        out.append(
            f"Masking across footprints ({surface}; `{d['command']}`, code at {d['code_commit'][:7]}): the brdfscale "
            "material with only its masking changed — the signed band bias where μ ≥ 8 against the truth / against "
            "the truth without shadow rays, the mean of its absolute values, and that mean over LEAN's (the "
            "target: ≤ 0.5)\n\n"
            + table(["material", *[f"μ∈[{a:g},{b:g})" for a, b in bands], "mean |·|", "÷ LEAN's"], rows)
        )
    return out


def visibility_diagnosis() -> list[str]:
    """experiments/render_visibility.py: the plane materials with the footprint mean normal (study 8's) and with the
    micro-geometry's visible mean normal, per surface the signed band bias where μ ≥ 8, and how far the normals
    differ per band."""
    path = RESULTS / "render_visibility" / "visibility.json"
    if not path.exists():
        return []
    d = json.loads(path.read_text())
    out = []
    for surface, record in d["surfaces"].items():
        bands, rows = far_signed_rows(record)
        differences = [
            [
                f"[{r['mu_band_px'][0]:g}, {r['mu_band_px'][1]:g})",
                f"{r['mean'][0]:+.3f} / {r['mean'][1]:+.3f}",
                f"{r['rms'][0]:.3f} / {r['rms'][1]:.3f}",
            ]
            for r in record["normal_differences"]
        ]
        out.append(
            f"The normal a pixel sees ({surface}; `{d['command']}`, code at {d['code_commit'][:7]}): the materials "
            "shaded with the footprint's mean texel slope (study 8's) and with the mean normal of the triangles the "
            "truth's own camera rays hit — the signed band bias where μ ≥ 8 against the truth / against the truth "
            "without shadow rays, and its mean |·|\n\n"
            + table(["material, normal", *[f"μ∈[{a:g},{b:g})" for a, b in bands], "mean |·|"], rows)
            + "\n\nand the visible normal's slope minus the footprint's per μ band, mean and rms, x / y (the camera "
            "looks along +y)\n\n" + table(["μ band", "mean, x / y", "rms, x / y"], differences)
        )
    return out


def render_validation() -> str:
    """Study 8 (experiments/render_validation.py): three plane materials against the micro-geometry truth."""
    paths = sorted((RESULTS / "render_validation").glob("*.json"))
    if not paths:
        return "(render_validation/*.json missing: run the study)"
    out = []
    for path in paths:
        d = json.loads(path.read_text())
        methods = list(d["errors"])
        bands = [b["mu_band_px"][0] for b in d["errors"][methods[0]]["bands"]]
        rows = []
        for m in methods:
            e = d["errors"][m]
            far = e["mu_ge_threshold"]
            rows.append(
                [
                    m,
                    f"{e['mean_abs']:.3f}",
                    f"{far['mean_abs']:.3f}",
                    f"{far['bias_mean_over_bands']:.3f}",
                    *[f"{b['bias']:.3f}" for b in e["bands"]],
                ]
            )
        speed = []
        for m in methods:
            q = d["equal_error"][m]

            def cell(key):
                x = q[key]
                if x["micro_geometry_spp"] is None:
                    return f"> {d['micro_geometry_ladder'][-1]['spp']} spp"
                return f"{x['micro_geometry_spp']:.3g} spp, {x['speedup']:.3g}×"

            speed.append(
                [m, f"{1e3 * q['shading_seconds']:.0f}", cell("mean_abs"), cell("far_mean_abs"), cell("far_bias")]
            )
        tab = d.get("tabulated_evolution") or []
        refused = [str(t["level_px"]) for t in tab if not t["exists"]]
        tab_line = (
            ""
            if not tab
            else (
                " Evolution with the measured histograms: "
                + ("exists at every level." if not refused else f"refused at levels {', '.join(refused)} texels.")
            )
        )
        ladder = ", ".join(f"{x['spp']}: {x['mean_abs']:.3f}" for x in d["micro_geometry_ladder"])
        out.append(
            f"**{d['surface']}** (tile {d['tile_size']}², α0 = {d['alpha0']:g}, image {d['image'][0]}×{d['image'][1]}, "
            f"μ from {d['mu_range_px'][0]:.2f} to {d['mu_range_px'][1]:.1f} texels, {d['instances']} instances of "
            f"{d['triangles_per_tile']:,} triangles; truth {d['reference_spp']} spp in {d['reference_seconds']:.0f} s; "
            f"brdfscale masking {'Smith' if d.get('brdfscale_masking', True) else 'off'}; Mitsuba α convention "
            f"checked to {d['alpha_convention_max_relative_error']:.2%}.{tab_line})\n\n"
            + table(
                [
                    "material",
                    "mean abs error",
                    "mean abs, μ ≥ 8",
                    "bias, μ ≥ 8",
                    *[f"bias μ∈[{b:g},{2 * b:g})" for b in bands],
                ],
                rows,
            )
            + "\n\nTime to equal error (micro-geometry spp at which its error equals the material's, and the ratio of "
            f"its render time to the material's shading time; micro-geometry mean abs error by spp: {ladder})\n\n"
            + table(["material", "shading ms", "mean abs", "mean abs, μ ≥ 8", "bias, μ ≥ 8"], speed)
        )
        diagnosis = d.get("diagnosis")
        if diagnosis:
            shadow = [
                [
                    f"[{x['mu_band_px'][0]:g}, {x['mu_band_px'][1]:g})",
                    f"{x['truth']:.3f}",
                    f"{x['without_shadow_rays']:.3f}",
                    f"{x['without_shadow_rays'] / x['truth'] - 1:+.1%}",
                ]
                for x in diagnosis["shadowing"]
            ]
            nest = [
                [
                    str(x["level_px"]),
                    *[
                        f"{x[a]['residual_excess_kurtosis']:.1f} / {x[a]['independent_excess_kurtosis']:.1f}"
                        for a in ("x", "y")
                    ],
                ]
                for x in diagnosis["nesting"]
            ]
            signed = diagnosis.get("signed_bias")
            signed_text = ""
            if signed and any(x["mu_band_px"][0] >= 8 for x in next(iter(signed.values()))):
                bands = [x["mu_band_px"] for x in next(iter(signed.values())) if x["mu_band_px"][0] >= 8]
                signed_rows = []
                for m, rows in signed.items():
                    far = [x for x in rows if x["mu_band_px"][0] >= 8]
                    mean = {k: sum(abs(x[k]) for x in far) / len(far) for k in ("truth", "without_shadow_rays")}
                    signed_rows.append(
                        [
                            m,
                            *[f"{x['truth']:+.3f} / {x['without_shadow_rays']:+.3f}" for x in far],
                            f"{mean['truth']:.3f} / {mean['without_shadow_rays']:.3f}",
                        ]
                    )
                signed_text = (
                    "\n\nthe signed band bias where μ ≥ 8 (band mean − the truth's, ÷ its mean), against the truth / "
                    "against the truth without shadow rays, and the mean of its absolute values over those bands (the "
                    "first is the tables' 'bias, μ ≥ 8')\n\n"
                    + table(["material", *[f"μ∈[{a:g},{b:g})" for a, b in bands], "mean |·|"], signed_rows)
                )
            out.append(
                f"Diagnosis ({d['surface']}): the truth's band means (÷ its mean) with and without the micro-geometry's"
                " shadow rays — shadowing that no plane material has\n\n"
                + table(["μ band", "truth", "without shadow rays", "change"], shadow)
                + signed_text
                + "\n\nand the within-footprint slope deviations' excess kurtosis, measured / what independent "
                "nesting (the seed's evolution) implies from the pixel and block-mean slopes\n\n"
                + table(["level (texels)", "x: measured / nesting", "y: measured / nesting"], nest)
            )
    out.extend(masking_diagnosis())
    out.extend(visibility_diagnosis())
    sphere = RESULTS / "render_sphere" / "sphere.json"
    if sphere.exists():
        d = json.loads(sphere.read_text())
        rows = [
            [
                f"{r['distance']:g}",
                str(r["sphere_pixels"]),
                f"{r['mu_centre_px']:.2f}",
                " / ".join(f"{q:.2f}" for q in r["mu_quantiles_px"]),
                f"{r['flux_relative_to_brdfscale']['naive']:.3f}",
                f"{r['flux_relative_to_brdfscale']['lean']:.3f}",
                f"{r['mean_abs_difference_to_brdfscale']['naive']:.3f}",
                f"{r['mean_abs_difference_to_brdfscale']['lean']:.3f}",
            ]
            for r in d["records"]
        ]
        out.append(
            f"**Sphere** (experiments/render_sphere.py: unit sphere, the di-3 law at one texel = {d['texel']:.3g}, "
            f"{d['image'][0]}² px, {d['spp']} spp, sun {d['light_angle_deg']:g}° from the view; no micro-geometry "
            "truth): the naive and LEAN materials against the brdfscale BSDF — flux over the sphere's pixels and "
            "per-pixel mean |Δ| (÷ brdfscale's mean)\n\n"
            + table(
                [
                    "distance",
                    "pixels",
                    "μ centre",
                    "μ 5 / 50 / 95 %",
                    "flux naive ÷ brdfscale",
                    "flux LEAN ÷ brdfscale",
                    "|Δ| naive",
                    "|Δ| LEAN",
                ],
                rows,
            )
        )
    return "\n\n".join(out)
