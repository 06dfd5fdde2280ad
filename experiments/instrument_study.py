"""Study 7: the seed's model and the masking-aware model against the ray-traced instrument (issue 32, items 5 and 6).

Ground truth: :func:`brdfscale.instrument.measure` — the height field meshed in Mitsuba 3, mirror pixel facets
(Beckmann micro-facets where stated), masking and shadowing by visibility rays, interreflection up to ``bounces``
reflections; its images follow the measurement sets' convention (the lobe ``A·g_μ(u)`` per unit slope area,
``u = m_s − m∞`` in each spot's own frame) and σ is its Monte Carlo standard error. Against each instrument image
three predictions are scored, all from the same height field:

* **seed** — the seed's nearly-flat model: :func:`brdfscale.synth.gonioreflectometer` (every pixel facet reflects
  the same light, no masking or shadowing; the lobe does not depend on the incidence);
* **masking** — the masking-aware model of ``lobes.AbstractLobe.evaluate(..., masking=lobes.SmithMasking())``:
  the seed's image times the height-correlated Smith ``G₂(i, o(u)) = 1/(1 + Λ(i) + Λ(o))``, Λ from the scale's
  own lobe (``stats.smith_lambda`` of the Gaussian of the mean and covariance of the within-facet slope density of
  :func:`brdfscale.synth.facet_statistics`: :func:`lambda_density`), ``o(u)`` the mirror direction of ``i`` about
  the half-vector of slope u (0 where it points into the surface).

(In the measurement convention the image is ``4 cosθ_o cos⁴θ_h ρ`` and the detector's solid angle per node
``4 (i·h) cos³θ_h d²u``: the light a facet intercepts, ∝ ``i·h``, cancels against it, so the microfacet model's image
is ``P₂₂(u)·G`` with no projected-area weight — synth's ``weighting="projected_area"`` is a flux density, not this
image, and is not scored.)

Per image (scale μ, incidence θ_i, bounces) the study records the energy ratio model ÷ instrument (sums over the
image grid; the instrument's relative MC error ``√Σσ² / Σ g``) and the relative L1 error ``Σ|g_model − g_inst| /
Σ g_inst`` with its MC floor ``√(2/π) Σσ / Σ g``. The error budget names the largest of three effects at each
(surface, μ, θ_i): *masking* (the L1 change G₂ makes to the seed's image), *interreflection* (the L1 between the
instrument with 3 bounces and with 1) and *nearly flat and the rest* (the masking-aware model's L1 against the
single-scattering instrument less its MC floor: the nearly-flat approximation, Smith's own assumptions and the
Gaussian Λ).

Surfaces: Gaussian-correlated heights (ℓ = 8 px, 256² px, periodic) scaled to rms slopes 0.05–0.5 at five incidences;
a heavy-tailed one (``h → c·sinh(h/c)``: slopes a Gaussian scale mixture, excess kurtosis > 1) at rms slope 0.2 and
the AFM file di-3 of tests/data/topographies (rms slope 0.19; plane removed; scales in pixel counts) at three
(:func:`anisotropic_surface` and the other real files are built in but left out of the default run: it was sized
to a shared, loaded 2-core machine; add them to :func:`configuration` given the time).

The evolution (item 5, as study 6 scored it on facet data): on the instrument's images at normal incidence, each
ordered pair of scales (coarser and finer) predicts the target image from the source image by the naive, the
second-moment and the evolved prediction of experiments/evolution_accuracy.py (:func:`brdfscale.evolve`, λ0 =
1/√facets), errors in L1 after the same resolution blur; the facet-statistics images give the same errors on facet
data for comparison.

The fits (item 6): the instrument's measurement sets of the Gaussian surfaces at every incidence fitted by the
library's default model (``fitting.fit``, what ``brdfscale fit`` runs before sampling) with ``masking=NoMasking()``
and ``masking=SmithMasking()``; the bias is the relative error of the recovered rms slope at the largest scale
against the facet statistics' (the truth of the geometry), per incidence.

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.instrument_study [--quick] [--out DIR]
(``--quick``: one 64² surface, two scales, two incidences, 10⁴ rays; written to a temporary folder unless --out.)
Writes experiments/results/instrument/instrument_study.json and instrument_study.png.
"""

import argparse
import functools
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np

import brdfscale as bs
from brdfscale import exr, geometry, lobes, stats, synth, topography
from experiments import evolution_accuracy as ea
from experiments._studies import l1_error, progress, save_figure, study_dir, tabulated_moments, write_results


STUDY = "instrument"
SIZE = 256
CORRELATION_PX = 8.0
RMS_SLOPES = (0.05, 0.1, 0.2, 0.3, 0.5)
SHAPED_RMS_SLOPE = 0.2
INCIDENCE_DEG = (0.0, 50.0, 70.0, 80.0, 85.0)
SCALES_PX = (64, 256)
SHAPED_INCIDENCE_DEG = (0.0, 75.0, 85.0)
PIXELS = 65
RAYS = 20_000
BOUNCES = (1, 3)
SEED = 0
REAL_FILES = ("di-3.di",)
"""The real file whose slopes make masking visible (rms slope 0.19; the other four are flatter than 0.03)."""
REAL_SCALES = 3
LAMBDA_SOURCE = 129
"""Nodes per axis of the within-facet slope density from which Λ is computed (a wide grid: Λ at grazing angles
depends on the density's tail)."""
EVOLUTION_FACTOR = 1.0
TARGET_RELATIVE = 0.02
SEED_OFF = 0.10
DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "topographies"


# -- surfaces ------------------------------------------------------------------------------------


def _scaled(field: synth.HeightField, rms_slope: float, heights=None, description=None) -> synth.HeightField:
    """``field`` (or ``heights`` on its grid) scaled to the given rms pixel slope (forward differences)."""
    h = np.asarray(field.heights if heights is None else heights, dtype=float)
    current = rms_pixel_slope(h, field.spacing[0])
    return synth.HeightField(h * (rms_slope / current), field.spacing, description=description or {})


def rms_pixel_slope(heights: np.ndarray, spacing: float = 1.0) -> float:
    """``√⟨|m|²⟩`` of the periodic forward-difference pixel slopes ``m = −∇h``."""
    mx = (np.roll(heights, -1, axis=1) - heights) / spacing
    my = (np.roll(heights, -1, axis=0) - heights) / spacing
    return float(np.sqrt(np.mean(mx**2 + my**2)))


def gaussian_surface(rms_slope: float, *, size: int = SIZE, seed: int = SEED) -> synth.HeightField:
    base = synth.spectral_field(stats.GaussianCorrelation(1.0, CORRELATION_PX), size=size, seed=seed)
    return _scaled(base, rms_slope, description={"surface": "gaussian", "rms_slope": rms_slope})


def anisotropic_surface(rms_slope: float = SHAPED_RMS_SLOPE, *, size: int = SIZE, seed: int = SEED):
    base = synth.spectral_field(stats.GaussianCorrelation(1.0, (6.0, 24.0)), size=size, seed=seed)
    return _scaled(base, rms_slope, description={"surface": "anisotropic", "rms_slope": rms_slope})


def heavy_tailed_surface(rms_slope: float = SHAPED_RMS_SLOPE, *, size: int = SIZE, seed: int = SEED):
    """``c·sinh(h/c)`` of a unit Gaussian field with c = 0.5: slopes ``cosh(h/c)·∇h``, a Gaussian scale mixture."""
    base = synth.spectral_field(stats.GaussianCorrelation(1.0, CORRELATION_PX), size=size, seed=seed)
    h = np.asarray(base.heights)
    c = 0.5
    shaped = c * np.sinh((h / h.std()) / c)
    return _scaled(base, rms_slope, shaped, {"surface": "heavy_tailed", "rms_slope": rms_slope})


def excess_kurtosis(field: synth.HeightField) -> float:
    h = np.asarray(field.heights)
    mx = np.ravel(np.roll(h, -1, axis=1) - h)
    return float(np.mean(mx**4) / np.mean(mx**2) ** 2 - 3)


def real_surface(name: str):
    """A file of tests/data/topographies (plane removed; masked pixels excluded) and its scales in length units."""
    field = topography.read(DATA / name, detrend="plane")
    ny, nx = field.shape
    largest = min(ny, nx) // 2
    pixels = np.unique(np.geomspace(8, largest, REAL_SCALES).round().astype(int))
    return field, [float(p) * float(field.spacing[0]) for p in pixels]


# -- the predictions -------------------------------------------------------------------------------


def nodes(extent: float, pixels: int) -> np.ndarray:
    x = np.linspace(-extent, extent, pixels)
    return np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)


def outgoing(incident: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The mirror direction of ``incident`` about the half-vector of slope ``u`` (…, 3)."""
    h = np.asarray(geometry.slope_to_direction(u))
    return np.asarray(geometry.reflect(np.broadcast_to(incident, h.shape), h))


def smith_g2(density: stats.AbstractSlopeDensity, incident: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``G₂(i, o(u))`` of the height-correlated Smith masking (0 where ``o`` points into the surface)."""
    o = outgoing(incident, u)
    above = o[..., 2] > 1e-9
    safe = np.where(above[..., None], o, np.array([0.0, 0.0, 1.0]))
    g2 = np.asarray(lobes.SmithMasking().g2(density, np.broadcast_to(incident, safe.shape), safe))
    return np.where(above, g2, 0.0)


PREDICTIONS = ("seed", "masking")


def lambda_density(lobe: stats.Tabulated) -> stats.Gaussian:
    """The Gaussian of the scale's lobe's mean and covariance, whose Λ ``stats.smith_lambda`` has in closed form.

    The generic path of ``stats.smith_lambda`` (a Fourier quadrature of the tabulated density along each direction's
    azimuth) costs about a second per direction for a 129² table on this machine, and every image needs Λ at its
    65² outgoing directions; the moment-matched Gaussian is what a Beckmann fit of the lobe would carry."""
    values, extent = np.asarray(lobe.values), float(np.asarray(lobe.extent).ravel()[0])
    mean, cov = tabulated_moments(values, extent)
    return stats.Gaussian(cov, mean=mean)


def predictions(field, mus, incident, extent, pixels) -> dict:
    """The two predictions' images (scale-major, as the instrument's): seed (the nearly-flat facet statistics) and
    masking (seed × G₂)."""
    seed = synth.gonioreflectometer(field, mus, incident, extent=extent, pixels=pixels)
    densities = {fs.mu: lambda_density(fs.lobe) for fs in synth.facet_statistics(field, mus, bins=LAMBDA_SOURCE)}
    u = nodes(extent, pixels)
    out = {name: [] for name in PREDICTIONS}
    for a in seed.images:
        flat = np.asarray(a.values, dtype=float)
        out["seed"].append(flat)
        out["masking"].append(flat * smith_g2(densities[a.mu], np.asarray(a.incident), u))
    return out


def scores(model: np.ndarray, image) -> dict:
    """Energy ratio and relative L1 error of ``model`` against an instrument image, with the image's MC errors."""
    g = np.asarray(image.values, dtype=float)
    sigma = np.zeros_like(g) if image.sigma is None else np.asarray(image.sigma, dtype=float)
    total = float(g.sum())
    return {
        "energy_ratio": float(model.sum()) / total,
        "l1": float(np.abs(model - g).sum()) / total,
        "mc_energy": float(np.sqrt((sigma**2).sum())) / total,
        "mc_l1_floor": float(math.sqrt(2 / math.pi) * sigma.sum()) / total,
    }


def relative_l1(a: np.ndarray, b: np.ndarray, reference: np.ndarray) -> float:
    return float(np.abs(a - b).sum() / reference.sum())


# -- one surface -----------------------------------------------------------------------------------


def incident_directions(thetas) -> np.ndarray:
    return np.array([[math.sin(math.radians(t)), 0.0, math.cos(math.radians(t))] for t in thetas])


def study_surface(field, mus, thetas, *, rays, bounces, seed, measure, label) -> dict:
    """The instrument's images (single scattering and ``max(bounces)``) of one surface at every (μ, θ_i) and the
    four predictions, scored; the error budget of each image."""
    incident = incident_directions(thetas)
    extent = synth.robust_extent(field)
    t0 = time.perf_counter()
    measured = {
        b: measure(field, mus, incident, extent=extent, pixels=PIXELS, rays=rays, bounces=b, seed=seed)
        for b in sorted(set(bounces))
    }
    seconds = time.perf_counter() - t0
    model = predictions(field, mus, incident, extent, PIXELS)
    single, most = measured[min(bounces)], measured[max(bounces)]
    records = []
    for k, image in enumerate(single.images):
        rec = {"surface": label, "mu": float(image.mu), "theta_i_deg": float(thetas[k % len(thetas)])}
        for b, mset in measured.items():
            for name, values in model.items():
                rec[f"{name}_bounces{b}"] = scores(values[k], mset.images[k])
        g1 = np.asarray(image.values, dtype=float)
        floor = rec[f"masking_bounces{min(bounces)}"]["mc_l1_floor"]
        rec["effects"] = {
            "masking": relative_l1(model["seed"][k], model["masking"][k], g1),
            "interreflection": relative_l1(np.asarray(most.images[k].values, dtype=float), g1, g1),
            "nearly_flat_and_rest": max(0.0, rec[f"masking_bounces{min(bounces)}"]["l1"] - floor),
        }
        rec["dominant"] = max(rec["effects"], key=rec["effects"].get)
        records.append(rec)
    return {"records": records, "seconds_measuring": round(seconds, 2), "extent": extent, "sets": measured}


# -- the evolution on instrument data --------------------------------------------------------------


def _level(mu, values, extent, fs) -> ea.Scale:
    return ea.Scale(mu, stats.Tabulated(np.maximum(values, 0.0), extent=extent), fs.slopes, fs.count)


def evolution_pairs(field, mset, extent) -> list:
    """Study 6's predictions (naive, second moment, evolved c = 1) of each ordered pair of scales, scored against
    the instrument's image at the target scale and against the facet-statistics image (normal incidence)."""
    normal = [p for p in mset.images if abs(float(p.incident[2]) - 1.0) < 1e-9]
    mus = [float(p.mu) for p in normal]
    facets = {fs.mu: fs for fs in synth.facet_statistics(field, mus, bins=PIXELS, extent=extent)}
    facet_images = synth.gonioreflectometer(field, mus, [0.0, 0.0, 1.0], extent=extent, pixels=PIXELS).images
    instrument = {p.mu: _level(p.mu, np.asarray(p.values, dtype=float), extent, facets[p.mu]) for p in normal}
    facet = {p.mu: _level(p.mu, np.asarray(p.values, dtype=float), extent, facets[p.mu]) for p in facet_images}
    out = []
    for source in mus:
        for target in mus:
            if source == target:
                continue
            rec = {"mu_from": source, "mu_to": target}
            for data, levels in (("instrument", instrument), ("facets", facet)):
                truth = ea.blur(levels[target].values, ea.RESOLUTION_NODES)
                pred = ea.predictions(levels[source], levels[target], factors=())
                values = {"naive": pred["naive"], "second_moment": pred["second_moment"]}
                try:
                    values["evolved"], rec[f"lambda_{data}"], _ = ea.evolved(
                        levels[source], levels[target], EVOLUTION_FACTOR
                    )
                except bs.NoBRDFAtScaleError:  # recorded: the library found no lobe at the target scale
                    values["evolved"], rec[f"refused_{data}"] = None, "NoBRDFAtScaleError"
                for name, v in values.items():
                    rec[f"{data}_{name}"] = (
                        None if v is None else l1_error(ea.blur(v, ea.RESOLUTION_NODES), truth, extent)
                    )
            out.append(rec)
    return out


# -- the fits on instrument data (item 6) ------------------------------------------------------------


def fit_set(mset, directory: Path, masking: str) -> dict:
    """``brdfscale fit`` (the default model; no sampling: ``--steps 0``) of one measurement set, with
    ``--masking masking``: the parameters it recovers (the amplitude among them), its χ²/dof and its verdict."""
    path = directory / "set.exr"
    if not path.exists():
        exr.write_measurements(str(path), mset)
    out = directory / f"fit_{masking}"
    argv = [sys.executable, "-m", "brdfscale", "fit", str(path), "--out", str(out), "--steps", "0", "--no-progress"]
    t0 = time.perf_counter()
    run = subprocess.run([*argv, "--masking", masking], capture_output=True, text=True, timeout=1800)
    rec = {"masking": masking, "exit_status": run.returncode, "seconds": round(time.perf_counter() - t0, 1)}
    report = out / "fit.json"
    if not report.exists():
        rec["error"] = run.stderr.strip().splitlines()[-1:] or ["(no message)"]
        return rec
    doc = json.loads(report.read_text())
    rec["model"] = doc.get("model", {}).get("kind")
    rec["parameters"] = {name: row.get("estimate_map") for name, row in doc.get("parameters", {}).items()}
    rec["amplitude"] = rec["parameters"].get("amplitude")
    rec["reduced_chi2"] = doc.get("optimisation", {}).get("reduced_chi2")
    rec["outcome"] = doc.get("outcome", {}).get("status")
    return rec


def fits(surface: dict, thetas, field, workdir: Path) -> list:
    """Each incidence's measurement set (all scales, bounces = the most) fitted without and with masking; the
    truth of the amplitude: the instrument's energy in the image grid (mirror facets reflect all light)."""
    mset = surface["sets"][max(surface["sets"])]
    out = []
    for theta in thetas:
        images = [p for p in mset.images if abs(math.degrees(math.acos(float(p.incident[2]))) - theta) < 1e-6]
        one = bs.MeasurementSet(images, dict(mset.metadata))
        directory = workdir / f"{surface['label']}_{theta:g}"
        directory.mkdir(parents=True, exist_ok=True)
        energy = float(np.mean([np.sum(np.asarray(p.values)) for p in images]))
        rec = {"surface": surface["label"], "theta_i_deg": theta, "rms_pixel_slope": rms_pixel_slope(field.heights)}
        rec["instrument_energy_in_grid"] = energy * (2 * surface["extent"] / (PIXELS - 1)) ** 2
        rec["fits"] = [fit_set(one, directory, masking) for masking in ("none", "smith")]
        out.append(rec)
    return out


# -- the whole study --------------------------------------------------------------------------------


def configuration(quick: bool) -> dict:
    if quick:
        return {
            "size": 64,
            "scales_px": [16, 64],
            "theta_i_deg": [0.0, 75.0],
            "shaped_theta_i_deg": [0.0, 75.0],
            "rays": 10_000,
            "bounces": [1, 2],
            "synthetic": [("gaussian", 0.2)],
            "real": [],
            "evolution": ["gaussian_0.2"],
            "fit_surfaces": [],
            "fit_theta_i_deg": [],
        }
    return {
        "size": SIZE,
        "scales_px": list(SCALES_PX),
        "theta_i_deg": list(INCIDENCE_DEG),
        "rays": RAYS,
        "bounces": list(BOUNCES),
        "synthetic": [("gaussian", s) for s in RMS_SLOPES] + [("heavy_tailed", SHAPED_RMS_SLOPE)],
        "real": list(REAL_FILES),
        "shaped_theta_i_deg": list(SHAPED_INCIDENCE_DEG),
        "evolution": ["gaussian_0.2", "heavy_tailed_0.2"],
        "fit_surfaces": ["gaussian_0.3"],
        "fit_theta_i_deg": [0.0, 80.0],
    }


BUILDERS = {"gaussian": gaussian_surface, "anisotropic": anisotropic_surface, "heavy_tailed": heavy_tailed_surface}


def surfaces(config: dict):
    """(label, field, scales in the field's length units, incidences, description) of every surface of the study:
    the Gaussian surfaces at every incidence, the anisotropic, heavy-tailed and real ones at fewer."""
    for kind, rms in config["synthetic"]:
        field = BUILDERS[kind](rms, size=config["size"])
        mus = [float(m) for m in config["scales_px"] if m <= config["size"]]
        info = {"kind": kind, "rms_slope": rms, "size": config["size"], "excess_kurtosis_x": excess_kurtosis(field)}
        thetas = config["theta_i_deg"] if kind == "gaussian" else config["shaped_theta_i_deg"]
        yield f"{kind}_{rms:g}", field, mus, thetas, info
    for name in config["real"]:
        field, mus = real_surface(name)
        info = {"kind": "real", "file": name, "shape": list(field.shape), "unit": field.unit}
        yield name, field, mus, config["shaped_theta_i_deg"], info


def run(*, quick: bool = False, out=None, measure=None, fit: bool = True) -> dict:
    """The study; ``measure`` defaults to :func:`brdfscale.instrument.measure` (a stand-in may be passed)."""
    if measure is None:
        from brdfscale import instrument

        measure = functools.partial(instrument.measure, progress=False)
    config = configuration(quick)
    directory = study_dir(STUDY, out) if out is not None or not quick else Path(tempfile.mkdtemp())
    started = time.perf_counter()
    records, described, evolution, fitted = [], {}, [], []
    with tempfile.TemporaryDirectory() as work:
        for label, field, mus, thetas, info in progress(list(surfaces(config)), desc="instrument study"):
            result = study_surface(
                field,
                mus,
                thetas,
                rays=config["rays"],
                bounces=config["bounces"],
                seed=SEED,
                measure=measure,
                label=label,
            )
            described[label] = {
                **info,
                "scales": mus,
                "extent": result["extent"],
                "seconds": result["seconds_measuring"],
            }
            records += result["records"]
            if label in config["evolution"]:
                mset = result["sets"][max(result["sets"])]
                evolution += [{"surface": label, **r} for r in evolution_pairs(field, mset, result["extent"])]
            if fit and label in config["fit_surfaces"]:
                result["label"] = label
                fitted += fits(result, config["fit_theta_i_deg"], field, Path(work))
    payload = {
        "config": {**config, "synthetic": [list(x) for x in config["synthetic"]], "pixels": PIXELS, "seed": SEED},
        "surfaces": described,
        "records": records,
        "evolution": evolution,
        "fits": fitted,
        "seconds": round(time.perf_counter() - started, 1),
    }
    payload["summary"] = summarise(payload)
    write_results(directory, "instrument_study", payload)
    if not quick:
        plot(payload, directory)
    payload["directory"] = str(directory)
    return payload


def _largest(records: list) -> list:
    """The records at each surface's largest scale (the spot that holds the whole roughness)."""
    top = {}
    for r in records:
        top[r["surface"]] = max(top.get(r["surface"], 0.0), r["mu"])
    return [r for r in records if r["mu"] == top[r["surface"]]]


def summarise(payload: dict) -> dict:
    """The benchmark's targets on the Gaussian surfaces (rms slope ≤ 0.3, θ_i ≤ 80°, the largest scale, the
    instrument with the most bounces) and the median errors of each prediction per surface."""
    most = max(payload["config"]["bounces"])
    largest = _largest(payload["records"])
    target_rows = [
        r
        for r in largest
        if r["surface"].startswith("gaussian_")
        and float(r["surface"].split("_")[1]) <= 0.3 + 1e-12
        and r["theta_i_deg"] <= 80.0
    ]

    def within(r, name):
        s = r[f"{name}_bounces{most}"]
        return abs(s["energy_ratio"] - 1) <= max(TARGET_RELATIVE, 2 * s["mc_energy"])

    seed_off = [r for r in target_rows if abs(r[f"seed_bounces{most}"]["energy_ratio"] - 1) > SEED_OFF]
    medians = {}
    for label in dict.fromkeys(r["surface"] for r in payload["records"]):
        rows = [r for r in payload["records"] if r["surface"] == label]
        medians[label] = {
            name: {
                "median_l1": float(np.median([r[f"{name}_bounces{most}"]["l1"] for r in rows])),
                "median_abs_energy_error": float(
                    np.median([abs(r[f"{name}_bounces{most}"]["energy_ratio"] - 1) for r in rows])
                ),
            }
            for name in PREDICTIONS
        }
    dominant = {}
    for r in largest:
        dominant.setdefault(r["surface"], {})[f"{r['theta_i_deg']:g}"] = r["dominant"]
    evo = payload["evolution"]
    evolution = {}
    for data in ("instrument", "facets"):
        for name in ("naive", "second_moment", "evolved"):
            values = [e[f"{data}_{name}"] for e in evo if e.get(f"{data}_{name}") is not None]
            evolution[f"{data}_{name}_median_l1"] = float(np.median(values)) if values else None
    return {
        "bounces_of_truth": most,
        "target_rows": len(target_rows),
        "masking_within_target": sum(within(r, "masking") for r in target_rows),
        "seed_within_target": sum(within(r, "seed") for r in target_rows),
        "seed_off_by_more_than_10pc": [[r["surface"], r["theta_i_deg"]] for r in seed_off],
        "masking_within_where_seed_off": sum(within(r, "masking") for r in seed_off),
        "medians": medians,
        "dominant_at_largest_scale": dominant,
        "evolution": evolution,
    }


def plot(payload: dict, directory: Path) -> list:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    most = max(payload["config"]["bounces"])
    largest = _largest(payload["records"])
    labels = [s for s in dict.fromkeys(r["surface"] for r in largest)]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    colours = plt.get_cmap("viridis")(np.linspace(0, 0.9, len(labels)))
    for label, colour in zip(labels, colours, strict=True):
        rows = sorted((r for r in largest if r["surface"] == label), key=lambda r: r["theta_i_deg"])
        theta = [r["theta_i_deg"] for r in rows]
        for ax, name, style in ((axes[0], "seed", "--"), (axes[0], "masking", "-")):
            ax.plot(
                theta,
                [r[f"{name}_bounces{most}"]["energy_ratio"] for r in rows],
                style,
                color=colour,
                label=f"{label} ({name})",
            )
        axes[1].plot(theta, [r[f"masking_bounces{most}"]["l1"] for r in rows], "-", color=colour, label=label)
        axes[1].plot(theta, [r[f"seed_bounces{most}"]["l1"] for r in rows], "--", color=colour)
    axes[0].axhspan(1 - TARGET_RELATIVE, 1 + TARGET_RELATIVE, color="0.85")
    axes[0].set(xlabel="θ_i (°)", ylabel="energy model ÷ instrument", title="seed (dashed), masking-aware (solid)")
    axes[1].set(xlabel="θ_i (°)", ylabel="relative L1 error", yscale="log", title="L1 against the instrument")
    axes[0].legend(fontsize=6, ncol=2)
    return [save_figure(fig, directory / "instrument_study.png")]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one small surface, two incidences, 10⁴ rays")
    parser.add_argument("--out", default=None, help="folder (default experiments/results/instrument/)")
    parser.add_argument("--no-fits", action="store_true", help="skip item 6's fits")
    args = parser.parse_args(argv)
    payload = run(quick=args.quick, out=args.out, fit=not args.no_fits)
    print(json.dumps(payload["summary"], indent=2))
    print(f"{payload['seconds']} s; written to {payload['directory']}")


if __name__ == "__main__":
    main()
