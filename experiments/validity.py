"""Study 3: where does the nearly-flat approximation break? (seed §2 footnote 1, docs/conventions.md §2)

The library's lobe model for mirror micro-facets is ``ρ(i, o) = P22(m_s) · F(i, o)`` with
``F = 1/(4 cosθ_o cos⁴θ_h)`` (:func:`brdfscale.geometry.microfacet_factor`) and P22 the
facet-slope density: every facet counts once, whatever its tilt. Brute force on the height
field instead reflects the light of every pixel facet exactly:

* outgoing direction ``o = reflect(i, n)`` (:func:`brdfscale.geometry.reflect`), with
  ``n = slope_to_direction(m)``;
* weight = intercepted flux relative to a flat pixel, ``max(0, n·i) / (n_z i_z)`` (facet
  area 1/n_z times its cosine), zero when o points into the surface (the light would
  scatter again: multiple scattering is not followed);
* optionally shadowing and masking: a ray from the facet centre towards i and towards o,
  marched over the periodic height field in steps of one pixel (bilinear heights); the
  facet counts only if both rays escape.

The model's reflected flux per unit half-slope area is ``P22(u) · ρ o_z · 4 (h·o) cos³θ_h /
i_z`` (dω_o = 4 (h·o) dω_h, dω_h = cos³θ_h d²m); both are histogrammed over u = m_s on the
same grid (48² bins over ±4 rms slopes) and compared by the relative L1 error

    E = Σ_bins |flux_model − flux_brute| / Σ flux_brute,

together with the albedo ratio Σ flux_model / Σ flux_brute. Surface: Gaussian-correlated
heights (ℓ = 8 px) scaled to a range of rms slopes; incidence in the x–z plane.

Run:  python -m experiments.validity [--size 256] [--seed 0]
Writes experiments/results/validity/validity.json and validity.png.
"""

import argparse
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np

from brdfscale import geometry, stats, synth
from experiments._studies import pixel_slopes, progress, save_figure, study_dir, write_results


CORRELATION_PX = 8.0
HIST_BINS = 48


def bilinear(heights: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Periodic bilinear interpolation of ``heights[j, k]`` at ``(x, y) = (k, j)`` (pixels)."""
    n = heights.shape[0]
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    i0, j0 = x0.astype(np.int64) % n, y0.astype(np.int64) % n
    i1, j1 = (i0 + 1) % n, (j0 + 1) % n
    return (
        heights[j0, i0] * (1 - fx) * (1 - fy)
        + heights[j0, i1] * fx * (1 - fy)
        + heights[j1, i0] * (1 - fx) * fy
        + heights[j1, i1] * fx * fy
    )


def escapes(heights: np.ndarray, x, y, z, d: np.ndarray) -> np.ndarray:
    """Whether rays from ``(x, y, z)`` (pixels; heights in pixel units) along unit ``d`` (…, 3)
    leave the periodic height field without passing below it (steps of one pixel)."""
    top = heights.max()
    horizontal = np.hypot(d[..., 0], d[..., 1])
    rise = d[..., 2] / np.maximum(horizontal, 1e-300)
    ex = np.where(horizontal > 0, d[..., 0] / np.maximum(horizontal, 1e-300), 0.0)
    ey = np.where(horizontal > 0, d[..., 1] / np.maximum(horizontal, 1e-300), 0.0)
    free = np.ones(x.shape, bool)
    active = (horizontal > 0) & (z < top)
    limit = heights.shape[0] // 2
    for t in range(1, limit + 1):
        idx = np.nonzero(active)[0]
        if idx.size == 0:
            break
        zt = z[idx] + t * rise[idx]
        below = bilinear(heights, x[idx] + t * ex[idx], y[idx] + t * ey[idx]) > zt
        free[idx[below]] = False
        active[idx[below | (zt >= top)]] = False
    return free


def reflected_flux(heights: np.ndarray, incident: np.ndarray) -> dict:
    """Per pixel facet: half-slope u, brute-force weights (with/without visibility), model weights."""
    m = pixel_slopes(heights).reshape(-1, 2)
    n = np.asarray(geometry.slope_to_direction(m))
    i = np.broadcast_to(incident, n.shape)
    o = np.asarray(geometry.reflect(i, n))
    cos_i = np.sum(n * i, axis=-1)
    up = o[:, 2] > 1e-9
    brute = np.where(up, np.maximum(cos_i, 0.0) / (n[:, 2] * incident[2]), 0.0)
    o_safe = np.where(up[:, None], o, np.array([0.0, 0.0, 1.0]))
    model = np.where(
        up,
        np.asarray(geometry.microfacet_factor(i, o_safe))
        * o[:, 2]
        * 4
        * np.sum(n * o_safe, -1)
        * np.asarray(geometry.solid_angle_per_slope_area(m))
        / incident[2],
        0.0,
    )
    size = heights.shape[0]
    jj, kk = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    x, y = kk.ravel() + 0.5, jj.ravel() + 0.5
    z = bilinear(heights, x, y) + 1e-9
    lit = brute > 0
    visible = np.zeros(len(m), bool)
    idx = np.nonzero(lit)[0]
    ok = escapes(heights, x[idx], y[idx], z[idx], np.broadcast_to(incident, (idx.size, 3)))
    idx = idx[ok]
    visible[idx[escapes(heights, x[idx], y[idx], z[idx], o[idx])]] = True
    return {"u": m, "brute": brute, "brute_masked": brute * visible, "model": model}


def compare(flux: dict, extent: float) -> dict:
    edges = np.linspace(-extent, extent, HIST_BINS + 1)

    def hist(w):
        return np.histogram2d(flux["u"][:, 0], flux["u"][:, 1], bins=[edges, edges], weights=w)[0]

    model = hist(flux["model"])
    out = {}
    for key in ("brute", "brute_masked"):
        ref = hist(flux[key])
        total = flux[key].sum()
        out[f"error_vs_{key}"] = float(np.abs(model - ref).sum() / total)
        out[f"albedo_ratio_vs_{key}"] = float(flux["model"].sum() / total)
        out[f"albedo_{key}"] = float(total / len(flux["u"]))
    out["albedo_model"] = float(flux["model"].sum() / len(flux["u"]))
    return out


def run(*, size: int, rms_slopes: list[float], angles_deg: list[float], seed: int, out=None) -> dict:
    directory = study_dir("validity", out)
    unit = synth.spectral_field(stats.GaussianCorrelation(1.0, CORRELATION_PX), size=size, seed=seed)
    unit_rms = float(np.sqrt(np.mean(pixel_slopes(unit.heights) ** 2)))  # per axis
    records = []
    for sigma in progress(rms_slopes, desc="rms slope"):
        heights = unit.heights * (sigma / unit_rms)
        for theta in angles_deg:
            t = np.radians(theta)
            incident = np.array([np.sin(t), 0.0, np.cos(t)])
            flux = reflected_flux(heights, incident)
            records.append({"rms_slope_per_axis": sigma, "theta_i_deg": theta, **compare(flux, 4 * sigma * np.sqrt(2))})
    payload = {
        "study": "validity of the nearly-flat approximation",
        "size": size,
        "seed": seed,
        "correlation_length_px": CORRELATION_PX,
        "rms_slopes_per_axis": rms_slopes,
        "theta_i_deg": angles_deg,
        "hist_bins": HIST_BINS,
        "masking": "shadowing and masking by ray marching over the periodic height field (1 px steps, "
        "bilinear heights); multiple scattering not followed",
        "records": records,
    }
    write_results(directory, "validity", payload)
    plot(payload, directory / "validity.png")
    return payload


def plot(payload: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for k, theta in enumerate(payload["theta_i_deg"]):
        rows = [r for r in payload["records"] if r["theta_i_deg"] == theta]
        s = [r["rms_slope_per_axis"] for r in rows]
        axes[0].plot(s, [r["error_vs_brute"] for r in rows], "o-", color=f"C{k}", label=f"θi = {theta:g}°")
        axes[1].plot(s, [r["error_vs_brute_masked"] for r in rows], "o-", color=f"C{k}")
        axes[2].plot(s, [r["albedo_ratio_vs_brute_masked"] for r in rows], "o-", color=f"C{k}")
    for ax, title in zip(
        axes, ("lobe error, no masking", "lobe error, with shadowing/masking", "albedo model / brute (masked)")
    ):
        ax.set_xscale("log")
        ax.set_xlabel("rms slope per axis")
        ax.set_title(title)
    axes[0].set_yscale("log")
    axes[1].set_yscale("log")
    axes[0].set_ylabel("relative L1 error")
    axes[0].legend(fontsize=8)
    save_figure(fig, path)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="output folder (default experiments/results/validity)")
    args = parser.parse_args()
    run(
        size=args.size,
        rms_slopes=[0.01, 0.03, 0.1, 0.2, 0.35, 0.5],
        angles_deg=[0.0, 30.0, 60.0, 75.0, 85.0],
        seed=args.seed,
        out=args.out,
    )


if __name__ == "__main__":
    main()
