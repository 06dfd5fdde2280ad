"""The fits on instrument data (issue 32 item 6): the default model on ray-traced measurement sets, with and without
masking in the forward model, scored against the field's own facet statistics.

Data: :func:`brdfscale.instrument.measure` (Mitsuba 3; mirror pixel facets, every whole μ × μ window a spot, each
aligned to its own mean plane, masking and shadowing by rays, interreflection up to :data:`BOUNCES` reflections; σ
its Monte Carlo standard error) of four surfaces — Gaussian-correlated heights of rms slope 0.1 and 0.3 and an
anisotropic one (ℓ = 6 × 24 px) of rms slope 0.2, all 256² px and periodic (experiments/instrument_study.py's
builders), and the AFM file di-3 of tests/data/topographies (256², plane removed) — at the scales 8, 32, 128 px and
the incidences 0°, 40°, 70°, 80° (azimuth 0: the incidence plane is x–z).

Fits: each incidence's set (all scales) by ``fitting.fit`` with the default model of ``brdfscale fit``
(:class:`fitting.AnisotropicModel`, a Gaussian lobe of full covariance and free centre at μ0 and a full ΔΣ(μ0, μk)
per coarser scale; fitting.fit's defaults) on ``fitting.Dataset.from_measurements(mset, masking=M)``, M = ``"none"``
(the seed's forward model) and ``"smith"`` (Smith's height-correlated G₂ of the scale's own lobe divided out,
docs/masking.md), and its verdict by ``fitting.assess``.

Truth. Two descriptions of the same field at the same windows (the instrument traces exactly those facets, so the
comparison has no sampling error of the surface — only the instrument's Monte Carlo error, which is in the fit's
standard errors):

* ``facet_statistics`` — what the issue asks for: ΔΣ = Σ(μ0) − Σ(μk) of :func:`brdfscale.synth.facet_statistics`
  (the nearly-flat offsets ``u = m − m_facet``; the seed's model of the lobe);
* ``aligned`` — what a mirror-faceted instrument that aligns each spot sees without masking (:func:`aligned_lobes`):
  each pixel facet's normal rotated by its spot's alignment (the smallest rotation taking the window's mean normal
  to z), its slope in that frame, weighted by its area projected on the spot's mean plane, the spots weighing
  equally; ΔΣ_aligned = Cov(g_μk) − Cov(g_μ0) of those lobes. The difference to ``facet_statistics`` is the
  nearly-flat term (the seed's linearisation of the rotation), independent of incidence and of masking.

The lobe at μ0 is compared too: the fit's base covariance ``C0`` against the aligned lobe's covariance plus the
variance per axis that the instrument's binning adds (:data:`BINNING_VARIANCE`: ``h²/12`` for nearest-node binning,
the default; ``h²/6`` for bilinear, cloud-in-cell shares, a tent of one pitch h).

Scores per fit: z = (fit − truth)/std_fit per ΔΣ component (xx, xy, yy; std the fit's Laplace standard error);
the relative bias of ΔΣ_xx, ΔΣ_yy (x lies in the incidence plane, where masking acts) and C0_xx, C0_yy; and the
*shift from normal incidence* z_shift = (ΔΣ(θ) − ΔΣ(0°))/√(std_θ² + std_0²), which leaves out every bias that does
not depend on the incidence (nearly-flat term, binning, lobe shape). The grazing-incidence bias is *removed* by a
masking choice on a surface when every ΔΣ and C0 component at 70° and 80° has |z_shift| ≤ 3 — recorded per
surface in ``summary``.

Why a verdict is not "ok" — four measurements, each of one candidate cause:

* *binning* (:func:`noise_correlation`): the noise surface is measured a second time with another seed; the
  whitened difference ``(a − b)/√(σ_a² + σ_b²)`` is pure Monte Carlo noise, and its lag-1 autocorrelation along rows
  and columns is what the detector's binning alone puts into any fit's residuals (its χ²/dof: σ's calibration).
  Bilinear (cloud-in-cell) shares of a ray spread uniformly over a cell give neighbouring nodes a correlation of
  exactly (2 · E[f(1 − f)] · E[b²]) / (4 · E[(1 − f)²] · E[b²]) = (1/3)/(4/3) = 1/4 (``CIC_LAG1``), above the
  adequacy test's 0.1 (``brdfscale.choices.ADEQUACY.max_lag1``), so with ``binning="bilinear"`` that test fails
  whatever the model; nearest-node binning (the instrument's default) leaves the errors independent;
* *the images* (:func:`image_moments`): the second moments of the 0° images against the aligned truth's;
* *the lobe model* (:func:`seed_control`): the seed's instrument (:func:`brdfscale.synth.gonioreflectometer`,
  nearly flat, no masking) imaging the same field at normal incidence, with Gaussian noise of the ray tracer's own
  σ, fitted by the same model — the model's adequacy for this field's lobes at this noise, without the ray tracer;
* *σ* (:func:`with_sigma_of`): the noise surface's sets fitted with the other seed's σ, an error estimate
  independent of the values.

Run:  nice -n 10 python -m experiments.instrument_fits [--quick] [--out DIR]
(an accuracy study, not a timing one: no bench lock; ``--quick``: one 64² surface, two scales, two incidences,
2·10⁴ rays, written to a temporary folder unless --out.)
Writes experiments/results/instrument_fits/instrument_fits.json.
"""

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np

import brdfscale as bs
from brdfscale import fitting, synth
from brdfscale.choices import ADEQUACY
from experiments import instrument_study as surfaces_of
from experiments._studies import study_dir, tabulated_moments, write_results


STUDY = "instrument_fits"
SIZE = 256
SCALES_PX = (8, 32, 128)
INCIDENCE_DEG = (0.0, 40.0, 70.0, 80.0)
GRAZING_DEG = 70.0
"""Incidences from this one on are *grazing* for the summary."""
PIXELS = 65
RAYS = 100_000
BOUNCES = 3
SEED = 0
NOISE_SEED = 1
MASKINGS = ("none", "smith")
SURFACES = (("gaussian", 0.1), ("gaussian", 0.3), ("anisotropic", 0.2), ("real", "di-3.di"))
NOISE_SURFACE = ("gaussian", 0.3)
NOISE_INCIDENCE_DEG = (0.0, 80.0)
MAX_Z = 3.0
CIC_LAG1 = 0.25
"""Lag-1 correlation of bilinearly binned Monte Carlo noise between neighbouring nodes (module docstring)."""


def configuration(quick: bool) -> dict:
    if quick:
        return {
            "size": 64,
            "scales_px": [8, 32],
            "theta_i_deg": [0.0, 70.0],
            "pixels": 33,
            "rays": 20_000,
            "bounces": 2,
            "surfaces": [["gaussian", 0.3]],
            "noise_surface": ["gaussian", 0.3],
            "noise_theta_i_deg": [0.0],
        }
    return {
        "size": SIZE,
        "scales_px": list(SCALES_PX),
        "theta_i_deg": list(INCIDENCE_DEG),
        "pixels": PIXELS,
        "rays": RAYS,
        "bounces": BOUNCES,
        "surfaces": [list(s) for s in SURFACES],
        "noise_surface": list(NOISE_SURFACE),
        "noise_theta_i_deg": list(NOISE_INCIDENCE_DEG),
    }


def label_of(kind: str, value) -> str:
    return value.split(".")[0] if kind == "real" else f"{kind}_{value:g}"


def surface(kind: str, value, config: dict):
    """``(field, scales in the field's length unit)`` of one surface of the study."""
    if kind == "real":
        field, _ = surfaces_of.real_surface(value)
    else:
        builder = {"gaussian": surfaces_of.gaussian_surface, "anisotropic": surfaces_of.anisotropic_surface}[kind]
        field = builder(value, size=config["size"])
    spacing = float(field.spacing[0])
    return field, [p * spacing for p in config["scales_px"] if p < min(field.shape)]


def incident(theta_deg: float) -> list:
    t = math.radians(theta_deg)
    return [math.sin(t), 0.0, math.cos(t)]


# -- the truth ---------------------------------------------------------------------------------------


def _rotate_to_z(n: np.ndarray, nf: np.ndarray) -> np.ndarray:
    """``R n`` with R the smallest rotation taking the unit vector ``nf`` to z (Rodrigues' form
    ``R x = x + v × x + v × (v × x)/(1 + c)``, ``v = nf × z``, ``c = nf·z``); ``nf`` broadcasts against ``n``."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(nf, z)
    c = nf[..., 2:3]
    vx = np.cross(v, n)
    return n + vx + np.cross(v, vx) / (1.0 + c)


def aligned_lobes(field: synth.HeightField, mu: float, *, rotate: bool = True) -> tuple[np.ndarray, ...]:
    """Mean (2,), covariance (2, 2) and excess kurtosis per axis (2,) of the lobe at scale ``mu`` as an aligning
    mirror-faceted instrument sees it without masking (module docstring): the spots are the whole windows of
    :func:`brdfscale.synth.facet_slopes`, weighing equally; within a spot each pixel facet of slope m (window mean
    m_f) reflects into the slope of its normal rotated by the spot's alignment, weighted by its area projected on the
    spot's plane, ``∝ (1 + m·m_f)/(1 + |m_f|²)`` per pixel (these sum to the spot's pixel count, as m_f is the mean
    of its m). ``rotate=False``: the nearly-flat offsets
    ``m − m_f`` with equal weights, whose covariance is the population form of
    ``Σ(pixel) − Σ(μ)`` of :func:`brdfscale.synth.facet_statistics`."""
    m = synth.facet_slopes(field, float(field.spacing[0]))  # pixel-facet slopes, (fy, fx, 2)
    by, bx = field.block(mu)
    nby, nbx = m.shape[0] // by, m.shape[1] // bx
    w = m[: nby * by, : nbx * bx].reshape(nby, by, nbx, bx, 2).transpose(0, 2, 1, 3, 4).reshape(nby * nbx, by * bx, 2)
    w = w[np.all(np.isfinite(w), axis=(1, 2))]  # windows touching an unmeasured pixel are no spot
    mf = w.mean(axis=1, keepdims=True)
    if rotate:
        n = np.concatenate([w, np.ones(w.shape[:-1] + (1,))], axis=-1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        nf = np.concatenate([mf, np.ones(mf.shape[:-1] + (1,))], axis=-1)
        nf /= np.linalg.norm(nf, axis=-1, keepdims=True)
        r = _rotate_to_z(n, nf)
        u = r[..., :2] / r[..., 2:3]
        weight = (1.0 + np.sum(w * mf, axis=-1)) / (1.0 + np.sum(mf * mf, axis=-1))
    else:
        u = w - mf
        weight = np.ones(w.shape[:-1])
    weight = weight / (w.shape[1] * w.shape[0])  # each spot's sum 1/spots (the area weights sum to its pixels)
    weight = weight / np.sum(weight)  # exact 1 (a rounding)
    u, weight = u.reshape(-1, 2), weight.ravel()
    mean = weight @ u
    d = u - mean
    cov = (d * weight[:, None]).T @ d
    variance = np.diag(cov)
    kurtosis = np.divide(weight @ d**4, variance**2, out=np.full(2, np.nan), where=variance > 0) - 3  # NaN: a point
    return mean, cov, kurtosis


BINNING_VARIANCE = {"nearest": 1 / 12, "bilinear": 1 / 6}
"""Variance per axis, in pitches², that the detector's binning adds to a lobe's covariance as the fit sees it: a
path counted in the node of its cell (uniform over a cell: h²/12) or shared bilinearly (a tent of one pitch: h²/6)."""


def binning_of(mset: bs.MeasurementSet) -> str:
    """The instrument's binning (``metadata["instrument"]["detector"]["binning"]``: its first word)."""
    return str(mset.metadata["instrument"]["detector"]["binning"]).split()[0]


def truth(field: synth.HeightField, mus: list, pitch: float, binning: str) -> dict:
    """The two truths of the module docstring at every scale: ΔΣ(μ0, μk) of the facet statistics and of the
    aligned lobes (k ≥ 1), and the aligned lobe at μ0 as the instrument's image holds it (its binning's variance
    :data:`BINNING_VARIANCE` added)."""
    statistics = synth.facet_statistics(field, mus, bins=17)
    aligned = [aligned_lobes(field, mu) for mu in mus]
    flat = [aligned_lobes(field, mu, rotate=False) for mu in mus]
    return {
        "facet_statistics": [(statistics[0].covariance - s.covariance).tolist() for s in statistics[1:]],
        "facet_statistics_std": [
            np.hypot(statistics[0].covariance_error, s.covariance_error).tolist() for s in statistics[1:]
        ],
        "nearly_flat_population": [(c - flat[0][1]).tolist() for _, c, _ in flat[1:]],
        "aligned": [(c - aligned[0][1]).tolist() for _, c, _ in aligned[1:]],
        "aligned_lobe_mean": [m.tolist() for m, _, _ in aligned],
        "aligned_lobe_covariance": [c.tolist() for _, c, _ in aligned],
        "aligned_lobe_excess_kurtosis": [k.tolist() for _, _, k in aligned],
        "binning": binning,
        "binning_variance": BINNING_VARIANCE[binning] * pitch**2,
        "C0": (aligned[0][1] + np.eye(2) * BINNING_VARIANCE[binning] * pitch**2).tolist(),
        "mean0": aligned[0][0].tolist(),
    }


# -- the fits ----------------------------------------------------------------------------------------


def fit_set(mset: bs.MeasurementSet, masking: str) -> dict:
    """The default model fitted to one measurement set with ``masking``; its estimates and verdict."""
    t0 = time.perf_counter()
    data = fitting.Dataset.from_measurements(mset, masking=masking)
    model = fitting.AnisotropicModel(len(data.scales))
    result = fitting.fit(model, data)
    outcome = fitting.assess(fitting.Problem(model, data), result)
    e = result.estimates
    return {
        "masking": masking,
        "optimiser": result.status,
        "outcome": outcome.status,
        "reason": outcome.reason,
        "problems": list(outcome.problems),
        "reduced_chi2": result.chi2 / result.dof,
        "scales": [
            {k: s.get(k) for k in ("mu", "width_px", "reduced_chi2", "chi2_p", "lag1_rows", "lag1_cols", "lag1_p")}
            for s in outcome.scales
        ],
        "amplitude": e["amplitude"],
        "C0": [[e["C0_xx"], e["C0_xy"]], [e["C0_xy"], e["C0_yy"]]],
        "C0_std": [[result.std.get(f"C0_{a}") for a in row] for row in (("xx", "xy"), ("xy", "yy"))],
        "mean": [e["mean_x"], e["mean_y"]],
        "delta_sigma": [{"mu": d["mu"], "value": d["value"], "std": d["std"]} for d in result.covariance_differences],
        "valid_pixels": data.n_data,
        "seconds": round(time.perf_counter() - t0, 1),
    }


def _z(value, std, reference) -> dict:
    value, reference = np.asarray(value, float), np.asarray(reference, float)
    std = np.asarray([[np.nan if s is None else s for s in row] for row in std], float)
    return {n: _finite((value[a, b] - reference[a, b]) / std[a, b]) for n, a, b in fitting.DIFFERENCE_ENTRIES}


def _finite(x) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None


def _relative(value, reference) -> dict:
    value, reference = np.asarray(value, float), np.asarray(reference, float)
    return {n: float(value[a, a] / reference[a, a] - 1) for n, a in (("xx", 0), ("yy", 1))}


def score(fit: dict, truths: dict) -> dict:
    """z-scores and relative biases of one fit against both truths (module docstring)."""
    rows = []
    for k, d in enumerate(fit["delta_sigma"]):
        rows.append(
            {
                "mu": d["mu"],
                "z_facet_statistics": _z(d["value"], d["std"], truths["facet_statistics"][k]),
                "z_aligned": _z(d["value"], d["std"], truths["aligned"][k]),
                "relative_bias_facet_statistics": _relative(d["value"], truths["facet_statistics"][k]),
                "relative_bias_aligned": _relative(d["value"], truths["aligned"][k]),
            }
        )
    return {
        "delta_sigma": rows,
        "C0_relative_bias": _relative(fit["C0"], truths["C0"]),
        "C0_z": _z(fit["C0"], fit["C0_std"], truths["C0"]),
        "mean_offset": (np.asarray(fit["mean"]) - np.asarray(truths["mean0"])).tolist(),
    }


def shift(fit: dict, normal: dict) -> dict:
    """``z_shift`` of ΔΣ (each coarser scale) and C0 between ``fit`` and the same masking's normal-incidence fit."""

    def z(a, sa, b, sb):
        out = {}
        for n, i, j in fitting.DIFFERENCE_ENTRIES:
            s = [sa[i][j], sb[i][j]]
            out[n] = None if None in s else _finite((a[i][j] - b[i][j]) / math.hypot(*s))
        return out

    rows = [
        {"mu": d["mu"], "z_shift": z(d["value"], d["std"], d0["value"], d0["std"])}
        for d, d0 in zip(fit["delta_sigma"], normal["delta_sigma"], strict=True)
    ]
    return {"delta_sigma": rows, "C0": z(fit["C0"], fit["C0_std"], normal["C0"], normal["C0_std"])}


# -- the noise of the instrument: why "inadequate" ------------------------------------------------------


def noise_correlation(a: bs.MeasurementSet, b: bs.MeasurementSet) -> list:
    """Per image of ``a`` and its image in ``b`` (same scale and incidence; two measurements of one surface with
    different seeds): χ²/dof of the whitened difference ``(a − b)/√(σ_a² + σ_b²)`` over the pixels either reached
    (σ's calibration) and its lag-1 autocorrelation along rows and columns (fitting.assess's statistic) over all
    pixels, as the fits see them."""
    out = []
    for p in a.images:  # the image of b at the same scale and incidence
        q = next(q for q in b.images if q.mu == p.mu and np.allclose(q.incident, p.incident))
        va, vb = np.asarray(p.values), np.asarray(q.values)
        sa, sb = np.asarray(p.sigma), np.asarray(q.sigma)
        r = (va - vb) / np.hypot(sa, sb)
        lit = (va > 0) | (vb > 0)
        valid = np.ones(r.shape, bool)
        rows, pairs = fitting.lag1_correlation(r, valid, 1)
        cols, _ = fitting.lag1_correlation(r, valid, 0)
        out.append(
            {
                "mu": p.mu,
                "theta_i_deg": round(math.degrees(math.acos(float(p.incident[2]))), 6),
                "reduced_chi2_lit": float(np.mean(r[lit] ** 2)),
                "lit_pixels": int(np.count_nonzero(lit)),
                "lag1_rows": rows,
                "lag1_cols": cols,
                "pairs": pairs,
            }
        )
    return out


def with_sigma_of(a: bs.MeasurementSet, b: bs.MeasurementSet) -> bs.MeasurementSet:
    """``a``'s values with the σ of ``b``'s image at the same scale and incidence: an estimate of the same Monte Carlo
    error made from other rays, so independent of ``a``'s values. The instrument's σ comes from the spread of its own
    batches, and where few rays land (a lobe's tails) a pixel that happened to get few gets a small σ too (zero rays:
    the one-count floor), so with its own σ a weighted fit leans towards the low pixels — towards narrower lobes; with
    an independent σ it does not. The fit of both says how much of a bias that makes."""
    images = []
    for p in a.images:
        q = next(q for q in b.images if q.mu == p.mu and np.allclose(q.incident, p.incident))
        images.append(bs.LobeImage(p.mu, p.incident, p.extent, np.asarray(p.values), np.asarray(q.sigma)))
    return bs.MeasurementSet(images, dict(a.metadata))


def image_moments(normal: bs.MeasurementSet, truths: dict) -> list:
    """Per scale: the variances (x, y) of the instrument's 0° image as its second moments over the grid, divided by
    the aligned truth's lobe variances plus the binning's — whether the images themselves hold the truth's lobes,
    whatever a model fitted to them makes of them."""
    out = []
    for k, image in enumerate(normal.images):
        _, cov = tabulated_moments(np.asarray(image.values), image.extent)
        truth = np.diag(truths["aligned_lobe_covariance"][k]) + truths["binning_variance"]
        out.append(
            {"mu": image.mu, "variance_ratio": (np.diag(cov) / truth).tolist(), "variance": np.diag(cov).tolist()}
        )
    return out


# -- the control: the seed's instrument at the same noise --------------------------------------------------


def seed_control(field: synth.HeightField, mus: list, normal: bs.MeasurementSet) -> bs.MeasurementSet:
    """:func:`brdfscale.synth.gonioreflectometer`'s exact images of the same field (the seed's nearly-flat
    instrument: no masking, no interreflection, the offsets ``m − m_f``) at normal incidence, with Gaussian noise of
    the instrument's own σ (``normal``: its 0° images) added and stored: fitted by the same model, it says whether
    the lobe model is adequate for this field's lobes at this noise, whatever the ray tracer adds."""
    first = normal.images[0]
    exact = synth.gonioreflectometer(field, mus, [0.0, 0.0, 1.0], extent=first.extent, pixels=first.size)
    rng = np.random.default_rng(SEED)
    images = []
    for image in exact.images:
        sigma = np.asarray(next(p for p in normal.images if p.mu == image.mu).sigma)
        values = np.asarray(image.values) + rng.normal(size=sigma.shape) * sigma
        images.append(bs.LobeImage(image.mu, image.incident, image.extent, values, sigma))
    return bs.MeasurementSet(images, dict(exact.metadata))


# -- the study -----------------------------------------------------------------------------------


def subset(mset: bs.MeasurementSet, theta_deg: float) -> bs.MeasurementSet:
    images = [p for p in mset.images if abs(math.degrees(math.acos(float(p.incident[2]))) - theta_deg) < 1e-6]
    return bs.MeasurementSet(images, dict(mset.metadata))


def study_surface(kind: str, value, config: dict, measure) -> tuple[dict, list, tuple]:
    """Measure one surface at every incidence, fit each incidence's set with each masking, score them."""
    field, mus = surface(kind, value, config)
    label = label_of(kind, value)
    extent = float(synth.robust_extent(field))
    pitch = 2 * extent / (config["pixels"] - 1)
    t0 = time.perf_counter()
    mset = measure(
        field,
        mus,
        [incident(t) for t in config["theta_i_deg"]],
        extent=extent,
        pixels=config["pixels"],
        rays=config["rays"],
        bounces=config["bounces"],
        seed=SEED,
    )
    measuring = time.perf_counter() - t0
    print(f"{label}: measured in {measuring:.0f} s", file=sys.stderr, flush=True)
    truths = truth(field, mus, pitch, binning_of(mset))
    fits = []
    for theta in config["theta_i_deg"]:
        one = subset(mset, theta)
        for masking in MASKINGS:
            rec = {"surface": label, "theta_i_deg": theta, **fit_set(one, masking)}
            print(f"{label} {theta:g}° {masking}: {rec['outcome']} ({rec['seconds']} s)", file=sys.stderr, flush=True)
            rec["score"] = score(rec, truths)
            fits.append(rec)
    moments = image_moments(subset(mset, 0.0), truths)
    control = {"surface": label, "theta_i_deg": 0.0, **fit_set(seed_control(field, mus, subset(mset, 0.0)), "none")}
    control["score"] = score(control, truths)  # its ΔΣ against the facet statistics (its C0 has bilinear binning)
    for rec in fits:
        normal = next(f for f in fits if f["masking"] == rec["masking"] and f["theta_i_deg"] == 0.0)
        rec["shift_from_normal"] = shift(rec, normal)
    described = {
        "label": label,
        "kind": kind,
        "value": value,
        "shape": list(field.shape),
        "spacing": float(field.spacing[0]),
        "unit": field.unit,
        "rms_pixel_slope": surfaces_of.rms_pixel_slope(np.asarray(field.heights), float(field.spacing[0])),
        "scales": mus,
        "scales_px": [round(mu / float(field.spacing[0])) for mu in mus],
        "extent": extent,
        "pitch": pitch,
        "truth": truths,
        "nearly_flat_term": [
            _relative(a, f) for a, f in zip(truths["aligned"], truths["facet_statistics"], strict=True)
        ],
        "seconds_measuring": round(measuring, 1),
        "control": control,
        "image_moments_0deg": moments,
        "instrument": {k: mset.metadata["instrument"].get(k) for k in ("variant", "detector", "rays", "bounces")},
    }
    return described, fits, (field, mus, extent, mset)


def _removed(fits: list, label: str, masking: str) -> dict:
    """Whether the grazing-incidence bias is removed (module docstring): the largest |z_shift| at θ ≥ 70°."""
    rows = [f for f in fits if f["surface"] == label and f["masking"] == masking and f["theta_i_deg"] >= GRAZING_DEG]
    values = []
    for f in rows:
        s = f["shift_from_normal"]
        values += [v for d in s["delta_sigma"] for v in d["z_shift"].values() if v is not None]
        values += [v for v in s["C0"].values() if v is not None]
    largest = max((abs(v) for v in values), default=None)
    return {"max_abs_z_shift": largest, "removed": largest is not None and largest <= MAX_Z}


def summarise(payload: dict) -> dict:
    fits = payload["fits"]
    labels = list(dict.fromkeys(f["surface"] for f in fits))
    per = {}
    for label in labels:
        per[label] = {}
        for masking in MASKINGS:
            rows = sorted(
                (f for f in fits if f["surface"] == label and f["masking"] == masking), key=lambda f: f["theta_i_deg"]
            )
            per[label][masking] = {
                **_removed(fits, label, masking),
                "coarsest_delta_sigma_xx_bias_vs_aligned": {
                    f"{f['theta_i_deg']:g}": f["score"]["delta_sigma"][-1]["relative_bias_aligned"]["xx"] for f in rows
                },
                "C0_xx_bias": {f"{f['theta_i_deg']:g}": f["score"]["C0_relative_bias"]["xx"] for f in rows},
                "outcomes": {f"{f['theta_i_deg']:g}": f["outcome"] for f in rows},
            }
    noise = payload["noise"]
    return {
        "grazing_bias": per,
        "removed_by_smith_on": [s for s in labels if per[s]["smith"]["removed"]],
        "biased_without_masking_on": [s for s in labels if not per[s]["none"]["removed"]],
        "noise_lag1_median": float(np.median([max(n["lag1_rows"], n["lag1_cols"]) for n in noise])) if noise else None,
        "noise_reduced_chi2_median": float(np.median([n["reduced_chi2_lit"] for n in noise])) if noise else None,
        "cic_lag1": CIC_LAG1,
        "max_lag1_threshold": ADEQUACY.max_lag1,
        "max_reduced_chi2_threshold": ADEQUACY.max_reduced_chi2,
    }


def run(*, quick: bool = False, out=None, measure=None) -> dict:
    """The study; ``measure`` defaults to :func:`brdfscale.instrument.measure` (without a progress bar)."""
    if measure is None:
        from brdfscale import instrument

        def measure(*args, **kw):
            return instrument.measure(*args, progress=False, **kw)

    config = configuration(quick)
    directory = study_dir(STUDY, out) if out is not None or not quick else Path(tempfile.mkdtemp())
    started = time.perf_counter()
    described, fits, noise, swapped = [], [], [], []
    for kind, value in config["surfaces"]:
        info, rows, (field, mus, extent, mset) = study_surface(kind, value, config, measure)
        described.append(info)
        fits += rows
        if [kind, value] == list(config["noise_surface"]):
            thetas = config["noise_theta_i_deg"]
            other = measure(
                field,
                mus,
                [incident(t) for t in thetas],
                extent=extent,
                pixels=config["pixels"],
                rays=config["rays"],
                bounces=config["bounces"],
                seed=NOISE_SEED,
            )
            same = bs.MeasurementSet([p for t in thetas for p in subset(mset, t).images], dict(mset.metadata))
            noise += [{"surface": info["label"], **n} for n in noise_correlation(same, other)]
            truths = info["truth"]
            for t in thetas:
                for masking in MASKINGS:
                    rec = {"surface": info["label"], "theta_i_deg": t, "sigma": f"seed {NOISE_SEED}"}
                    rec.update(fit_set(with_sigma_of(subset(mset, t), subset(other, t)), masking))
                    rec["score"] = score(rec, truths)
                    swapped.append(rec)
    payload = {
        "config": {**config, "seed": SEED, "noise_seed": NOISE_SEED, "maskings": list(MASKINGS)},
        "surfaces": described,
        "fits": fits,
        "noise": noise,
        "sigma_swap": swapped,
        "seconds": round(time.perf_counter() - started, 1),
    }
    payload["summary"] = summarise(payload)
    write_results(directory, STUDY, payload)
    payload["directory"] = str(directory)
    return payload


def table(payload: dict) -> str:
    """The Markdown table of the fits: per surface and incidence, without / with masking."""
    head = (
        "| surface | θ_i | χ²/dof | outcome | ΔΣ_xx bias (coarsest) | ΔΣ_yy bias | C0_xx bias "
        "| max z_shift ΔΣ | max \\|z\\| vs aligned |\n|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    by = {(f["surface"], f["theta_i_deg"], f["masking"]): f for f in payload["fits"]}
    for s, theta in dict.fromkeys((f["surface"], f["theta_i_deg"]) for f in payload["fits"]):
        cells = {m: by[(s, theta, m)] for m in MASKINGS}

        def both(fn, fmt):
            return " / ".join(fmt.format(fn(cells[m])) for m in MASKINGS)

        def zmax(f, key):
            values = [abs(v) for d in f["score"]["delta_sigma"] for v in d[key].values() if v is not None]
            return max(values, default=float("nan"))

        def zshift(f):
            rows = f["shift_from_normal"]["delta_sigma"]
            values = [abs(v) for d in rows for v in d["z_shift"].values() if v is not None]
            return max(values, default=0.0)

        lines.append(
            f"| {s} | {theta:g}° | {both(lambda f: f['reduced_chi2'], '{:.2f}')} | "
            f"{both(lambda f: f['outcome'], '{}')} | "
            f"{both(lambda f: 100 * f['score']['delta_sigma'][-1]['relative_bias_aligned']['xx'], '{:+.1f} %')} | "
            f"{both(lambda f: 100 * f['score']['delta_sigma'][-1]['relative_bias_aligned']['yy'], '{:+.1f} %')} | "
            f"{both(lambda f: 100 * f['score']['C0_relative_bias']['xx'], '{:+.1f} %')} | "
            f"{both(zshift, '{:.1f}')} | {both(lambda f: zmax(f, 'z_aligned'), '{:.1f}')} |"
        )
    return "\n".join(lines)


RESULT = Path(__file__).resolve().parent / "results" / STUDY / f"{STUDY}.json"


def block(path: Path = RESULT) -> str:
    """The generated block of docs/instrument.md, "Fits of instrument data", from the committed JSON
    (experiments/benchmarks_page.py splices it in; tests/test_experiments_smoke.py checks the page is current)."""
    if not path.exists():
        return f"({path.name} missing: run the study)"
    d = json.loads(path.read_text())
    c, s = d["config"], d["summary"]
    binning = sorted({x["truth"]["binning"] for x in d["surfaces"]})
    lines = [
        f"{c['rays']:,} rays per image, bounces {c['bounces']}, {c['pixels']}² px, {'/'.join(binning)} binning; "
        f"fields {c['size']}² px, scales {c['scales_px']} px; seed {c['seed']}; run time {d['seconds']:.0f} s "
        f'({d["machine"].get("cpu_count", "?")} CPUs, shared). Each cell: `masking="none"` / `"smith"`; '
        "biases relative to the aligned truth, ΔΣ at the coarsest scale; z_shift against the same masking's 0° fit.",
        "",
        table(d),
        "",
        "**Grazing-incidence bias removed?** (every ΔΣ and C0 component at θ_i ≥ "
        f"{GRAZING_DEG:g}° within {MAX_Z:g} standard errors of the same masking's 0° fit)",
        "",
        "| surface | none: max \\|z_shift\\| | smith: max \\|z_shift\\| | removed by smith |",
        "|---|---|---|---|",
    ]
    for x in d["surfaces"]:
        g = s["grazing_bias"][x["label"]]
        lines.append(
            f"| {x['label']} | {g['none']['max_abs_z_shift']:.1f} | {g['smith']['max_abs_z_shift']:.1f} | "
            f"{'yes' if g['smith']['removed'] else 'no'} |"
        )
    lines += [
        "",
        '**Why the verdict is not ok at normal incidence** (0°, `masking="none"`): the instrument\'s fit beside the '
        "control (the seed's instrument imaging the same field, with Gaussian noise of the instrument's σ) and the "
        "truths: the μ0 lobe's excess kurtosis (aligned, x / y), the nearly-flat term (aligned ΔΣ_xx ÷ facet "
        "statistics' − 1, coarsest scale); biases of C0_xx against the aligned lobe (binning added) and of ΔΣ_xx "
        "(coarsest) against the aligned truth (the control's against the facet statistics).",
        "",
        "| surface | χ²/dof: instrument / control | outcome: instrument / control | μ0 lobe excess kurtosis "
        "| nearly-flat term | 0° image's variance_xx ÷ truth's, per scale | C0_xx bias: instrument / control "
        "| ΔΣ_xx bias: instrument / control |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for x in d["surfaces"]:
        f = next(
            f for f in d["fits"] if f["surface"] == x["label"] and f["theta_i_deg"] == 0 and f["masking"] == "none"
        )
        k, ctl = x["truth"]["aligned_lobe_excess_kurtosis"][0], x["control"]
        ratios = ", ".join(f"{m['variance_ratio'][0]:.3f}" for m in x.get("image_moments_0deg", []))
        lines.append(
            f"| {x['label']} | {f['reduced_chi2']:.2f} / {ctl['reduced_chi2']:.2f} | {f['outcome']} / {ctl['outcome']} "
            f"| {k[0]:.2f} / {k[1]:.2f} | {100 * x['nearly_flat_term'][-1]['xx']:+.1f} % "
            f"| {ratios} "
            f"| {100 * f['score']['C0_relative_bias']['xx']:+.1f} % / "
            f"{100 * ctl['score']['C0_relative_bias']['xx']:+.1f} % "
            f"| {100 * f['score']['delta_sigma'][-1]['relative_bias_aligned']['xx']:+.1f} % / "
            f"{100 * ctl['score']['delta_sigma'][-1]['relative_bias_facet_statistics']['xx']:+.1f} % |"
        )
    if s["noise_lag1_median"] is not None:
        lines += [
            "",
            f"Monte Carlo noise alone (two seeds, {d['noise'][0]['surface']}, {len(d['noise'])} images): median lag-1 "
            f"autocorrelation {s['noise_lag1_median']:.3f} (adequacy threshold {s['max_lag1_threshold']:g}; bilinear "
            f"binning would give {s['cic_lag1']:g}), median χ²/dof of the whitened difference "
            f"{s['noise_reduced_chi2_median']:.2f}.",
        ]
    lines += [""] if d.get("sigma_swap") else []
    for r in d.get("sigma_swap", []):
        own = next(
            f
            for f in d["fits"]
            if (f["surface"], f["theta_i_deg"], f["masking"]) == (r["surface"], r["theta_i_deg"], r["masking"])
        )
        lines.append(
            f"- σ of seed {d['config']['noise_seed']} instead of its own, {r['surface']} at {r['theta_i_deg']:g}° "
            f"(`{r['masking']}`): C0_xx bias {100 * own['score']['C0_relative_bias']['xx']:+.1f} % → "
            f"{100 * r['score']['C0_relative_bias']['xx']:+.1f} %, ΔΣ_xx bias "
            f"{100 * own['score']['delta_sigma'][-1]['relative_bias_aligned']['xx']:+.1f} % → "
            f"{100 * r['score']['delta_sigma'][-1]['relative_bias_aligned']['xx']:+.1f} %, χ²/dof "
            f"{own['reduced_chi2']:.2f} → {r['reduced_chi2']:.2f}."
        )
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one 64² surface, two scales, two incidences")
    parser.add_argument("--out", default=None, help="folder (default experiments/results/instrument_fits/)")
    args = parser.parse_args(argv)
    payload = run(quick=args.quick, out=args.out)
    print(table(payload))
    print(json.dumps(payload["summary"], indent=2))
    print(f"{payload['seconds']} s; written to {payload['directory']}")


if __name__ == "__main__":
    main()
