"""The tables of docs/results.md, from the studies' JSON files (experiments/results/<study>/).

``python experiments/benchmarks_page.py`` writes them into the page's generated blocks, with
the benchmarks' tables.
"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _bench import RESULTS, table


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

