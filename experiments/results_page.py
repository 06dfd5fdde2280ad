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
    out = [(f"Field {d['size']}² px, seed {d['seed']}. Entries: violation V / permutation floor "
           "(V ≈ floor: consistent within sampling noise); `*`: fewer than 10 % of the facets off the "
           "lattice origin (the test has lost its resolution there).")]
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
            r = next((r for r in d["records"] if r["surface"] == name and r["window"] == "gaussian" and r["mu_px"] == mu), None)
            if r is not None:
                cross = r["total_variance"] - r["within_variance"] - r["between_variance"]
                rows.append([name, str(mu), f"{r['within_variance']:.3g}", f"{r['between_variance']:.3g}",
                             f"{cross / r['total_variance']:+.3f}"])
    out.append("\n**Second moments, Gaussian window** (box windows: cross term 0 by construction)\n\n"
               + table(["surface", "μ", "Var r (within)", "Var M (between)", "cross term / Var m"], rows))
    return "\n".join(out)


def evolution() -> str:
    d = load("evolution_accuracy", "evolution_accuracy")
    cs = d["lambda_factors"]
    ev = [f"evolved_c{c:g}" for c in cs]
    header = ["surface / direction", "naive", "second moment", *[f"evolved c={c:g}" for c in cs],
              *[f"median E_ev/E_2nd (c={c:g})" for c in cs], *[f"pairs with E_ev ≤ ½ E_2nd (c={c:g})" for c in cs]]
    rows = []
    for key, s in d["summary"].items():
        rows.append([key, f"{s['median_error_naive']:.3f}", f"{s['median_error_second_moment']:.3f}",
                     *[f"{s[f'median_error_{e}']:.3f}" for e in ev],
                     *[f"{s[f'median_ratio_{e}_to_second_moment']:.2f}" for e in ev],
                     *[f"{s[f'pairs_{e}_meeting_target_ratio_le_0.5']}/{s['pairs']}" for e in ev]])
    out = [(f"Field {d['size']}² px, scales {d['scales_px']} px and ∞, {d['bins']}² nodes, resolution "
           f"σ_r = {d['resolution_nodes']:g} nodes. Median L1 error over the pairs of each direction:\n"),
           table(header, rows)]
    rows = []
    for r in d["records"]:
        if r["surface"] in ("scratched", "blazed"):
            rows.append([r["surface"], f"{r['mu_from']}→{r['mu_to']}", f"{r['error_naive']:.3f}",
                         f"{r['error_second_moment']:.3f}", *[f"{r[f'error_{e}']:.3f}" for e in ev],
                         *[f"{r[f'lambda_{e}']:.3g}" for e in ev]])
    out.append("\n**Non-Gaussian surfaces, every pair** (λ: the regularisation evolve accepted)\n\n" + table(
        ["surface", "μ0→μ", "naive", "second moment", *[f"evolved c={c:g}" for c in cs], *[f"λ (c={c:g})" for c in cs]],
        rows))
    return "\n".join(out)


def validity() -> str:
    d = load("validity", "validity")
    thetas = d["theta_i_deg"]
    out = [(f"Field {d['size']}² px, correlation length {d['correlation_length_px']:g} px. Entries: E without "
           "masking / E with shadowing+masking / albedo ratio model ÷ brute (masked).")]
    rows = []
    for s in d["rms_slopes_per_axis"]:
        cells = []
        for t in thetas:
            r = next(r for r in d["records"] if r["rms_slope_per_axis"] == s and r["theta_i_deg"] == t)
            cells.append(f"{r['error_vs_brute']:.3f} / {r['error_vs_brute_masked']:.3f} / {r['albedo_ratio_vs_brute_masked']:.2f}")
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
            rows.append([m, f"{e['relative_mean_abs']:.3f}", f"{e['relative_rms']:.2f}",
                         *[f"{b['relative_bias']:.3f}" for b in e["bands"]]])
        lam = ", ".join(f"{lv['level_px']}: {lv['lambda']:.3g}" for lv in d["levels"])
        out.append(f"**{d['surface']}** (heights × {d['slope_scale']:g}, α0 = {d['alpha0']:g}, image "
                   f"{d['image'][0]}×{d['image'][1]}, texture {d['texture_size']}², μ from {d['mu_range_px'][0]:.2f} "
                   f"to {d['mu_range_px'][1]:.1f} texels; λ per level {lam})\n\n" + table(
                       ["method", "mean abs error", "RMS error", *[f"bias μ∈[{b:g},{2 * b:g})" for b in bands]], rows))
    return "\n\n".join(out)



def _param_text(params: dict) -> str:
    return ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items()
                     if k not in ("alpha_from", "alpha_to", "alpha_lobe", "x0", "honoured_tol"))


def stability() -> str:
    d = load("stability", "stability")
    s = d["summary"]
    t = s["totals"]
    out = [(f"{t['tried']} cases: {t['good']} good (accurate, or refused with the library's error where no result "
            f"exists), {t['limit']} at a documented limit, {t['bad']} bad; NaN {t['nan']}, Inf {t['inf']} in the "
            f"returned values; non-finite results on valid input: {t['nonfinite_on_valid_input']} (target 0 — "
            f"{'met' if t['nonfinite_on_valid_input'] == 0 else '**not met**'}). Evolution targets: tol "
            f"{d['evolve_tol']['float64']:g} (float64), {d['float32_target']:g} of the peak (float32).\n")]
    rows = []
    for p in s["by_path"]:
        where = "; ".join(f"{_param_text(f['params'])}: {f['status']}"
                          + ("" if f["error"] is None else f" ({f['error']:.1e})") for f in p["failing"][:4])
        if len(p["failing"]) > 4:
            where += f"; … ({len(p['failing'])} in all)"
        rows.append([p["kind"], p["path"], p["dtype"], str(p["tried"]), str(p["good"]), str(p["limit"]), str(p["bad"]),
                     str(p["nan"]), str(p["inf"]), "–" if p["max_error"] is None else f"{p['max_error']:.1e}",
                     where or "–"])
    out.append(table(["kind", "path", "dtype", "tried", "good", "limit", "bad", "NaN", "Inf", "largest error (accurate)",
                      "not accurate at"], rows))
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
            rows.append([case, f"{count:.0e}", f"{1 / count ** 0.5:.2g}", f"{best:.3f}",
                         f"{runs[0]['best_fixed_lambda']:.2g}", *cells])
        seeds = len({r["seed"] for r in n["runs"]})
        out.append(f"\n**Coarse → fine under noise** ({n['nodes']}² nodes, Poisson noise, {seeds} seed(s) per level; error: "
                   f"{n['error']}; entries: the largest ratio over the seeds of a rule's error to the best fixed λ's, "
                   "and the λ it chose for seed 0)\n")
        out.append(table(["case", "counts at peak", "noise at peak", "best fixed λ error (median)", "best fixed λ (seed 0)",
                          *[f"{r} ratio" for r in rules]], rows))
        summary = "; ".join(f"{r}: largest ratio {v['max_ratio']:.2f}, median {v['median_ratio']:.2f}, "
                            f"{v['runs_within_2']}/{v['runs']} runs within 2×" for r, v in n["summary"].items())
        out.append(f"\n{summary}. Default rule `{n['default_rule']}`; target ({n['target']}): "
                   f"{'met' if n['target_met'] else '**not met**'}.")
    return "\n".join(out)


def stability_figures(directory: Path | None = None) -> list:
    """Redraw the stability study's figures from its committed JSON (into ``directory``,
    default the study's folder): ``python -m experiments.benchmarks_page`` does it with the
    tables, and tests/test_experiments_smoke.py checks the committed PNGs are what the JSON gives."""
    from experiments import stability

    return stability.plot(load("stability", "stability"), directory or RESULTS / "stability")
