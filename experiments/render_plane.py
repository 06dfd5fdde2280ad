"""Study 4: a plane receding from near to far, rendered with a fine-scale material.

Scene: a pinhole camera at height 1 above the plane z = 0, pitched 18° down, vertical
field of view 32°, looks along +y; a directional light straight ahead at 8° elevation
(a low sun: a glint band across the middle of the image). The plane carries a tiled
height field (a :func:`brdfscale.synth.named_surface` with its heights multiplied by
``slope_scale``, default 4, so that the glint covers a good part of the image; texel
pitch τ = 0.01) whose texels
are micro-facets with a Beckmann lobe of roughness α0 (the BRDF at μ0 = 1 texel). A
pixel's footprint grows from about one texel at the bottom of the image to tens of
texels near the horizon.

* ground truth — every pixel supersampled with S × S jittered rays, S = clamp(⌈2μ⌉, 1, 48)
  (μ: the footprint in texels, √area), each ray shading its own texel:
  ``ρ = F(i, o) · g_α0(m_s(i, o) − m_texel)``;
* the three filtered renders shade once per pixel at the footprint's mean texel slope M
  (the ideal mip-mapped normal, averaged over the same rays) with a lobe for the scale μ,
  blended linearly in log₂ μ between the levels b = 1, 2, 4, … texels:
  naive — g_α0 unchanged; second moment — a Gaussian with covariance α0²/2·I + Σ_s(1) −
  Σ_s(b) (LEAN/Toksvig); evolved — ``brdfscale.evolve(Beckmann(α0), s_1, s_b, "grid",
  regularisation=λ)`` with the measured tabulated statistics and λ = c/√(facets at b),
  increased ×3 while the library reports no BRDF. Negative lobe values (regularisation
  ringing) are clipped to 0 for shading; the smallest is recorded.

Masking/shadowing and the m-dependence of the geometric factors are ignored in all four,
so the comparison isolates the scale evolution (study 3 measures the rest).
Errors: relative to the truth's mean radiance, per pixel (mean |Δ|, RMS) and after
averaging pixels in bands of equal μ (a factor 2 wide; bias without the sparkle noise
that no statistical model can reproduce).

Run:  python -m experiments.render_plane [--width 192] [--height 128]
Writes experiments/results/render_plane/<surface>.{json,exr,png} and <surface>_lobes.exr.
"""

import argparse
import math
from pathlib import Path

import equinox as eqx
import jax


jax.config.update("jax_enable_x64", True)

import numpy as np
import OpenEXR
from scipy import ndimage

from brdfscale import exr, geometry, lobes, stats, synth
from experiments._studies import (
    atomic_write,
    evolve_accepted,
    gaussian_density,
    node_grid,
    pixel_slopes,
    progress,
    save_figure,
    second_moment_covariance,
    study_dir,
    tabulated_moments,
    write_results,
)


TEXEL = 0.01
CAMERA_HEIGHT = 1.0
PITCH_DEG = 18.0
VFOV_DEG = 32.0
LIGHT_ELEVATION_DEG = 8.0
MAX_SUPERSAMPLING = 48
LOBE_NODES = 129
EVOLVE_GRID = 256
LAMBDA_FACTOR = 3.0
METHODS = ("naive", "second_moment", "evolved")


class Camera:
    """Pinhole camera at (0, 0, H) looking along +y, pitched down; rows go downwards."""

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        p = math.radians(PITCH_DEG)
        self.forward = np.array([0.0, math.cos(p), -math.sin(p)])
        self.right = np.array([1.0, 0.0, 0.0])
        self.up = np.cross(self.right, self.forward)
        self.half = math.tan(math.radians(VFOV_DEG) / 2)

    def hit(self, col, row):
        """Plane points (…, 2) and unit view rays (…, 3) for continuous pixel coordinates."""
        x = (2 * col / self.width - 1) * self.half * self.width / self.height
        y = (1 - 2 * row / self.height) * self.half
        d = self.forward + x[..., None] * self.right + y[..., None] * self.up
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        if np.any(d[..., 2] >= 0):
            raise ValueError("a pixel looks above the horizon; lower the pitch or the field of view")
        t = CAMERA_HEIGHT / -d[..., 2]
        return (t[..., None] * d)[..., :2], d


def footprints(camera: Camera) -> np.ndarray:
    """μ per pixel: √(area of the pixel's footprint) in texels (finite differences of hits)."""
    row, col = np.mgrid[0 : camera.height, 0 : camera.width] + 0.5
    p, _ = camera.hit(col, row)
    pc, _ = camera.hit(col + 1, row)
    pr, _ = camera.hit(col, row + 1)
    a, b = pc - p, pr - p
    return np.sqrt(np.abs(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])) / TEXEL


def texel_slopes(slopes: np.ndarray, points: np.ndarray) -> np.ndarray:
    n = slopes.shape[0]
    k = np.floor(points[..., 0] / TEXEL).astype(np.int64) % n
    j = np.floor(points[..., 1] / TEXEL).astype(np.int64) % n
    return slopes[j, k]


@eqx.filter_jit
def _factor_and_half_slope(i, o):
    return geometry.microfacet_factor(i, o), geometry.half_slope(i, o)


@eqx.filter_jit
def _texel_rho(lobe, i, o, m):
    return geometry.microfacet_factor(i, o) * lobe.density(geometry.half_slope(i, o) - m)


def padded(fn, *arrays):
    """Call a jitted ``fn`` on arrays (n, …) padded to a power-of-two length (one compilation
    per size class instead of one per shape); returns NumPy results cut back to n."""
    n = arrays[0].shape[0]
    size = max(1024, 1 << (n - 1).bit_length())
    padded_arrays = [np.concatenate([a, np.repeat(a[-1:], size - n, axis=0)]) for a in arrays]
    out = fn(*padded_arrays)
    return tuple(np.asarray(x)[:n] for x in out) if isinstance(out, tuple) else np.asarray(out)[:n]


def shade(incident, view, lobe_at) -> np.ndarray:
    """``ρ = F(i, o) · lobe_at(m_s(i, o))`` with o = −view (view: (n, 3))."""
    o = -view
    factor, ms = padded(_factor_and_half_slope, np.broadcast_to(incident, o.shape), o)
    return factor * lobe_at(ms)


def render_truth(camera, slopes, mu, incident, beckmann, seed) -> tuple[np.ndarray, np.ndarray]:
    """Supersampled truth and the footprint's mean texel slope per pixel."""
    rng = np.random.default_rng(seed)
    truth = np.zeros((camera.height, camera.width))
    mean_slope = np.zeros((camera.height, camera.width, 2))
    for r in progress(range(camera.height), desc="truth rows", leave=False):
        for s_val in np.unique(np.clip(np.ceil(2 * mu[r]), 1, MAX_SUPERSAMPLING).astype(int)):
            cols = np.nonzero(np.clip(np.ceil(2 * mu[r]), 1, MAX_SUPERSAMPLING).astype(int) == s_val)[0]
            grid = (np.arange(s_val)[:, None] + rng.random((cols.size, s_val, s_val, 2))) / s_val  # jittered
            col = cols[:, None, None] + grid[..., 0]
            row = r + np.swapaxes(grid[..., 1], 1, 2)
            points, view = camera.hit(col, row)
            m = texel_slopes(slopes, points)
            flat_view = view.reshape(-1, 3)
            values = padded(
                lambda i, o, mm: _texel_rho(beckmann, i, o, mm),
                np.broadcast_to(incident, flat_view.shape),
                -flat_view,
                m.reshape(-1, 2),
            )
            truth[r, cols] = values.reshape(m.shape[:-1]).mean(axis=(1, 2))
            mean_slope[r, cols] = m.mean(axis=(1, 2))
    return truth, mean_slope


def level_lobes(field, alpha0: float, levels: list[int]) -> dict:
    """Per level b: naive, second-moment and evolved lobes as functions of u, plus records."""
    beckmann = stats.Beckmann(alpha0)
    stats_at = {fs.block[1]: fs for fs in synth.facet_statistics(field, levels, bins=LOBE_NODES)}  # square pixels
    s1 = stats_at[1].slopes
    _, cov1 = tabulated_moments(np.asarray(s1.values), float(s1.extent[0]))
    extent = 4 * math.sqrt(alpha0**2 / 2 + np.trace(cov1)) + float(np.max(np.abs(pixel_slopes(field.heights))))
    u = node_grid(extent, LOBE_NODES)
    h = 2 * extent / (LOBE_NODES - 1)
    tables, funcs, records = [], {m: [] for m in METHODS}, []
    for b in progress(levels, desc="lobes", leave=False):
        sb = stats_at[b]
        _, covb = tabulated_moments(np.asarray(sb.slopes.values), float(sb.slopes.extent[0]))
        cov, _ = second_moment_covariance(np.eye(2) * alpha0**2 / 2, cov1, covb, h / 4)
        lam = 0.0 if b == 1 else LAMBDA_FACTOR / math.sqrt(sb.count)
        values, lam, _ = evolve_accepted(
            lobes.Beckmann(alpha0),
            s1,
            sb.slopes,
            lambda lobe: np.asarray(lobe.density(u)),
            regularisation=lam,
            size=EVOLVE_GRID,
        )
        tables.append(values)
        records.append(
            {
                "level_px": b,
                "lambda": lam,
                "evolved_min_over_peak": float(values.min() / values.max()),
                "second_moment_cov": cov.tolist(),
                "facets": sb.count,
            }
        )
        funcs["naive"].append(lambda q: gaussian_density(q, np.zeros(2), np.eye(2) * alpha0**2 / 2))
        funcs["second_moment"].append(lambda q, c=cov: gaussian_density(q, np.zeros(2), c))
        clipped = np.maximum(values, 0.0)
        funcs["evolved"].append(lambda q, v=clipped: _bilinear(v, extent, q))
    table = exr.LobeTable(
        np.asarray(levels, float),
        extent,
        np.stack(tables),
        {"what": "evolved lobes g_b of a Beckmann micro lobe", "alpha0": alpha0},
    )
    return {"funcs": funcs, "records": records, "table": table, "beckmann": beckmann}


def _bilinear(values: np.ndarray, extent: float, q: np.ndarray) -> np.ndarray:
    n = values.shape[0]
    g = (q + extent) / (2 * extent) * (n - 1)
    return ndimage.map_coordinates(values, [g[..., 1].ravel(), g[..., 0].ravel()], order=1, cval=0.0).reshape(
        q.shape[:-1]
    )


def render_filtered(camera, mu, mean_slope, incident, funcs, levels) -> np.ndarray:
    """Shade once per pixel with the lobe for its scale, blended in log₂ μ between levels."""
    row, col = np.mgrid[0 : camera.height, 0 : camera.width] + 0.5
    _, view = camera.hit(col, row)
    pos = np.clip(np.log2(np.maximum(mu, 1.0)), 0, len(levels) - 1)
    lo = np.minimum(np.floor(pos).astype(int), len(levels) - 2)
    w = pos - lo
    out = np.zeros(mu.shape)
    for k in range(len(levels)):
        weight = np.where(lo == k, 1 - w, 0.0) + np.where(lo + 1 == k, w, 0.0)
        sel = weight > 0
        if np.any(sel):
            offsets = mean_slope[sel]
            out[sel] += weight[sel] * shade(incident, view[sel], lambda u, f=funcs[k], m=offsets: f(u - m))
    return out


def errors(images: dict, mu: np.ndarray) -> dict:
    truth = images["truth"]
    scale = truth.mean()
    bands = np.floor(np.log2(np.maximum(mu, 1.0))).astype(int)
    out = {}
    for m in METHODS:
        diff = images[m] - truth
        banded = []
        for b in np.unique(bands):
            sel = bands == b
            banded.append(
                {
                    "mu_band_px": [2.0**b, 2.0 ** (b + 1)],
                    "pixels": int(sel.sum()),
                    "relative_bias": float(abs(images[m][sel].mean() - truth[sel].mean()) / scale),
                    "relative_mean_abs": float(np.abs(diff[sel]).mean() / scale),
                }
            )
        out[m] = {
            "relative_mean_abs": float(np.abs(diff).mean() / scale),
            "relative_rms": float(np.sqrt(np.mean(diff**2)) / scale),
            "bands": banded,
        }
    return out


def write_exr(path: Path, images: dict) -> None:
    """All images (and |error| maps) as channels ``<name>.Y`` of one float32 EXR, atomically."""
    channels = {f"{k}.Y": np.ascontiguousarray(v, dtype=np.float32) for k, v in images.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    atomic_write(path, lambda tmp: OpenEXR.File(header, channels).write(tmp))


def run(
    *, surface: str, size: int, width: int, height: int, alpha0: float, slope_scale: float, seed: int, out=None
) -> dict:
    directory = study_dir("render_plane", out)
    base = synth.named_surface(surface, size=size, seed=seed)
    field = synth.HeightField(
        base.heights * slope_scale, base.spacing, description={**base.description, "slope_scale": slope_scale}
    )
    slopes = pixel_slopes(field.heights)
    camera = Camera(width, height)
    mu = footprints(camera)
    levels = [2**k for k in range(math.ceil(math.log2(max(mu.max(), 2))) + 1) if 2**k <= size // 8]
    incident = np.array([0.0, math.cos(math.radians(LIGHT_ELEVATION_DEG)), math.sin(math.radians(LIGHT_ELEVATION_DEG))])
    lobes_ = level_lobes(field, alpha0, levels)
    images = {}
    images["truth"], mean_slope = render_truth(camera, slopes, mu, incident, lobes_["beckmann"], seed + 1)
    for m in METHODS:
        images[m] = render_filtered(camera, mu, mean_slope, incident, lobes_["funcs"][m], levels)
    err = errors(images, mu)
    for m in METHODS:
        images[f"abs_error_{m}"] = np.abs(images[m] - images["truth"])
    write_exr(directory / f"{surface}.exr", images)
    exr.write_lobe_table(directory / f"{surface}_lobes.exr", lobes_["table"], overwrite=True)
    payload = {
        "study": "render: plane receding from near to far",
        "surface": surface,
        "surface_description": synth.SURFACES[surface][0],
        "texture_size": size,
        "seed": seed,
        "image": [width, height],
        "alpha0": alpha0,
        "slope_scale": slope_scale,
        "texel": TEXEL,
        "camera_height": CAMERA_HEIGHT,
        "pitch_deg": PITCH_DEG,
        "vfov_deg": VFOV_DEG,
        "light_elevation_deg": LIGHT_ELEVATION_DEG,
        "mu_range_px": [float(mu.min()), float(mu.max())],
        "levels_px": levels,
        "max_supersampling": MAX_SUPERSAMPLING,
        "lambda_factor": LAMBDA_FACTOR,
        "levels": lobes_["records"],
        "errors": err,
    }
    write_results(directory, surface, payload)
    plot(images, mu, err, directory / f"{surface}.png", surface)
    return payload


def plot(images: dict, mu: np.ndarray, err: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = np.percentile(images["truth"], 99.5)
    names = ("truth", *METHODS)
    fig, axes = plt.subplots(2, 4, figsize=(16, 6.2))
    for ax, name in zip(axes[0], names):
        ax.imshow(np.clip(images[name] / top, 0, 1) ** (1 / 2.2), cmap="gray", vmin=0, vmax=1)
        ax.set_title(name if name == "truth" else f"{name} (mean |Δ| {err[name]['relative_mean_abs']:.2f})")
    axes[1, 0].imshow(np.log2(np.maximum(mu, 0.5)), cmap="viridis")
    axes[1, 0].set_title("log₂ footprint μ [texels]")
    for ax, name in zip(axes[1, 1:], METHODS):
        ax.imshow(images[f"abs_error_{name}"] / top, cmap="magma", vmin=0, vmax=0.5)
        ax.set_title(f"|{name} − truth|")
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(title)
    save_figure(fig, path)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=192)
    parser.add_argument("--height", type=int, default=128)
    parser.add_argument("--size", type=int, default=1024, help="texture size (texels)")
    parser.add_argument("--alpha0", type=float, default=0.04, help="Beckmann roughness of one texel")
    parser.add_argument("--slope-scale", type=float, default=4.0, help="factor on the named surface's heights")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--surfaces", nargs="+", default=["scratched", "blazed"])
    parser.add_argument("--out", default=None, help="output folder (default experiments/results/render_plane)")
    args = parser.parse_args()
    for surface in args.surfaces:
        run(
            surface=surface,
            size=args.size,
            width=args.width,
            height=args.height,
            alpha0=args.alpha0,
            slope_scale=args.slope_scale,
            seed=args.seed,
            out=args.out,
        )


if __name__ == "__main__":
    main()
