"""A sphere at several distances (issue 33 item 3): the brdfscale BSDF against roughconductor (LEAN) and unchanged.

Scene: a unit sphere at the origin, a pinhole camera at distance d (vertical field of view :data:`FOV_DEG`,
``SIZE``² pixels), a directional light 45° from the view direction. The sphere's surface is the measured di-3
topography's statistics (experiments/render_validation.py: the :class:`brdfscale.stats.MeasuredScaleLaw` of its
facets, one texel = :data:`TEXEL` scene units, Beckmann α0 = 0.04 at μ0 = 1 texel), shaded three ways, all through
:func:`brdfscale.render.FootprintIntegrator` (direct lighting):

* ``naive`` — ``roughconductor`` Beckmann α0 (the μ0 BRDF unchanged);
* ``lean`` — ``roughconductor`` Beckmann with LEAN's ``α_u, α_v = √(2 C_xx), √(2 C_yy)`` of
  ``C(μ_c) = α0²/2·I + Σ(1) − Σ(μ_c)`` at the footprint μ_c of the sphere's centre pixel (one roughness per
  distance, as an engine would pick a mip level per object; the small correlation C_xy dropped);
* ``brdfscale`` — :func:`brdfscale.render.bsdf` (closed form), μ from every pixel's own footprint: it grows
  towards the silhouette (``1/cos`` of the view angle) where a fixed roughness cannot follow.

The footprint image is the film's mean over each pixel's samples, misses counting 0: at the silhouette (pixels
partly covered) it reads low, while the BSDF sees each sample's own footprint. No micro-geometry ground truth:
the measured tile displaced onto a sphere at these distances needs ~10⁸ triangles (not feasible on this CPU within
the study's budget); what the study shows is where and by how much the three materials differ, per distance, and
the footprint across the sphere.

Run:  python -m experiments.render_sphere  →  experiments/results/render_sphere/sphere.{json,png}
"""

import argparse
import math

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np

from brdfscale import lobes
from experiments import render_validation as rv
from experiments._studies import save_figure, study_dir, write_results


DISTANCES = (10.0, 40.0, 160.0)
FOV_DEG = 12.0
SIZE = 160
SPP = 16
TEXEL = 10.0 * math.radians(FOV_DEG) / SIZE / 2  # the nearest distance's centre pixel covers 2 texels
LEVELS = [1, 2, 4, 8, 16, 32, 64]
LIGHT_ANGLE_DEG = 45.0


def scene(mi, distance: float, bsdf) -> object:
    angle = math.radians(LIGHT_ANGLE_DEG)
    return mi.load_dict(
        {
            "type": "scene",
            "sensor": {
                "type": "perspective",
                "fov": FOV_DEG,
                "fov_axis": "y",
                "near_clip": 1e-3,
                "to_world": mi.ScalarTransform4f().look_at(origin=[0, -distance, 0], target=[0, 0, 0], up=[0, 0, 1]),
                "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": SPP},
            },
            "ball": {"type": "sphere", "radius": 1.0, "bsdf": bsdf},
            "sun": {
                "type": "directional",
                "direction": [-math.sin(angle), math.cos(angle), 0.0],
                "irradiance": 1.0,
            },
        }
    )


def run(*, out=None, figures: bool = True) -> dict:
    from brdfscale import render

    directory = study_dir("render_sphere", out)
    mi = rv.mitsuba()
    field = rv.height_field("di-3", 512)
    stats_ = rv.level_statistics(field, rv.ALPHA0, LEVELS)
    law = stats_["law"]
    ours = render.bsdf(lobes.Beckmann(rv.ALPHA0), law, mu0=1.0, texel=TEXEL, variant=rv.VARIANT)
    integrator = render.FootprintIntegrator(max_depth=2)
    footprint = render.FootprintIntegrator(output="footprint")
    records, images = [], {}
    for d in DISTANCES:
        mu = np.asarray(mi.render(scene(mi, d, ours), integrator=footprint, seed=0))[..., 0] / TEXEL
        hit = mu > 0
        centre = float(mu[SIZE // 2, SIZE // 2])
        cov = (
            np.eye(2) * rv.ALPHA0**2 / 2
            + np.asarray(law.slope_covariance(1.0))
            - np.asarray(law.slope_covariance(min(max(centre, 1.0), LEVELS[-1])))
        )
        materials = {
            "naive": rv.roughconductor(mi, rv.ALPHA0),
            "lean": rv.roughconductor(mi, math.sqrt(2 * cov[0, 0]), math.sqrt(2 * cov[1, 1])),
            "brdfscale": ours,
        }
        frame = {}
        for name, bsdf in materials.items():
            frame[name] = np.asarray(mi.render(scene(mi, d, bsdf), integrator=integrator, seed=1))[..., 0]
        images[d] = {**frame, "mu": mu}
        sums = {name: float(frame[name][hit].sum()) for name in frame}
        records.append(
            {
                "distance": d,
                "sphere_pixels": int(hit.sum()),
                "mu_centre_px": centre,
                "mu_quantiles_px": [float(q) for q in np.quantile(mu[hit], [0.05, 0.5, 0.95])],
                "lean_alpha_uv": [math.sqrt(2 * cov[0, 0]), math.sqrt(2 * cov[1, 1])],
                "flux": sums,
                "flux_relative_to_brdfscale": {k: v / sums["brdfscale"] for k, v in sums.items()},
                "mean_abs_difference_to_brdfscale": {
                    k: float(np.abs(frame[k][hit] - frame["brdfscale"][hit]).mean() / frame["brdfscale"][hit].mean())
                    for k in ("naive", "lean")
                },
            }
        )
    payload = {
        "study": "a sphere at several distances: brdfscale BSDF vs roughconductor (LEAN) vs unchanged",
        "surface": "di-3",
        "alpha0": rv.ALPHA0,
        "texel": TEXEL,
        "fov_deg": FOV_DEG,
        "image": [SIZE, SIZE],
        "spp": SPP,
        "light_angle_deg": LIGHT_ANGLE_DEG,
        "ground_truth": None,
        "records": records,
    }
    write_results(directory, "sphere", payload)
    if figures:
        plot(images, directory / "sphere.png")
    return payload


def plot(images: dict, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ("naive", "lean", "brdfscale", "mu")
    fig, axes = plt.subplots(len(images), len(names), figsize=(3.2 * len(names), 3.2 * len(images)))
    for row, (d, frame) in zip(axes, images.items()):
        top = np.percentile(frame["brdfscale"], 99.5) or 1.0
        for ax, name in zip(row, names):
            if name == "mu":
                ax.imshow(np.log2(np.maximum(frame["mu"], 0.5)), cmap="viridis")
                ax.set_title(f"log₂ μ [texels], d = {d:g}")
            else:
                ax.imshow(np.clip(frame[name] / top, 0, 1) ** (1 / 2.2), cmap="gray", vmin=0, vmax=1)
                ax.set_title(f"{name}, d = {d:g}")
            ax.set_xticks([])
            ax.set_yticks([])
    save_figure(fig, path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="output folder (default experiments/results/render_sphere)")
    args = parser.parse_args(argv)
    run(out=args.out)


if __name__ == "__main__":
    main()
