"""Render validation on micro-geometry (issue 33 item 3): three plane materials against the displaced surface.

Scene: study 4's (experiments/render_plane.py) — a pinhole camera 1 unit above the plane, pitched 18° down, vertical
field of view 32°, a directional light (irradiance 1) straight ahead at 8° elevation — in the length unit of one
texel (the camera at 100 texels; a texel is 0.01 of study 4's unit). The surface is a periodic height field tiled over
the visible plane (one shared mesh, :func:`brdfscale.instrument.mesh`, placed by Mitsuba instances):

* ``di-3`` — the measured AFM topography tests/data/topographies/di-3.di (256², pitch 39 nm, rms slope 0.19), its
  central ``size/2`` square mirrored into a periodic ``size``² tile (even reflections: continuous heights, slope
  statistics symmetrised), heights in pixel units (slopes unchanged);
* ``anisotropic`` — :func:`brdfscale.synth.named_surface` ``"anisotropic"`` (Gaussian-correlated, ℓ = 6 × 24 px) with
  heights × :data:`ANISOTROPIC_SLOPE_SCALE` (rms slopes ≈ 0.13 along x, 0.03 along y).

Ground truth: the height field displaced as geometry, each triangle a Beckmann micro-facet BRDF of roughness α0 (the
base lobe at μ0 = 1 texel; Mitsuba's ``roughconductor``, ``material="none"``: Fresnel 1), rendered by a direct-lighting
tracer (camera rays jittered uniformly over each pixel = box pixel filter, one shadow ray each; no interreflection,
as none of the plane models has it) at ``reference_spp`` samples per pixel. The three plane materials shade each pixel
once, at the pixel centre's view direction, on a plane whose normal is the footprint's mean texel slope M (the ideal
mip-mapped normal: texel slopes averaged over S × S jittered points of the pixel's footprint, S = clamp(⌈μ⌉, 1, 16)),
with the lobe for the footprint μ (texels, √area of the pixel's footprint):

* ``naive`` — (a) ``roughconductor`` Beckmann α0 unchanged;
* ``lean`` — (b) ``roughconductor`` Beckmann with the LEAN/Toksvig roughness of Σ(μ): slope covariance
  ``C(μ) = α0²/2·I + Σ(1) − Σ(μ)`` (Σ: covariance of the facet slopes at scale μ,
  :func:`brdfscale.synth.facet_statistics`), ``alpha_u, alpha_v = √(2 λ₁), √(2 λ₂)`` with λ the eigenvalues of C
  and the tangent frame turned to its eigenvectors. Convention: Mitsuba's Beckmann α satisfies α² = 2σ² for a slope
  variance σ² per axis — its microfacet.h evaluates ``D(m) = exp(−(m_x²/α_u² + m_y²/α_v²)/cos²θ)/(π α_u α_v cos⁴θ)``,
  i.e. the slope density ``exp(−s_x²/α_u² − s_y²/α_v²)/(π α_u α_v)``; :func:`alpha_convention_error` checks it on the
  plugin itself. C is blended linearly in log₂ μ between the levels b = 1, 2, 4, … texels (the renders of the two
  neighbouring levels are blended);
* ``brdfscale`` — (c) :func:`brdfscale.render.bsdf` of ``Beckmann(α0)`` at μ0 = 1 texel with the surface's measured
  scale law (:class:`brdfscale.stats.MeasuredScaleLaw` of the facet statistics at the levels: Gaussian ``Σ(μ)``,
  linear in ln μ between them), Smith masking (height-correlated) of the plugin; the plugin reads μ from the
  interaction's uv partials, filled here with the pixel's footprint. For a Gaussian law the evolved lobe is the
  Gaussian of covariance C(μ) — LEAN's — so (b) and (c) differ by the masking term, the lobe's orientation (a shear
  of the slope plane here, a rotated frame in (b)) and Mitsuba's α-clamping, not by the lobe's shape. The material
  one would want for a non-Gaussian surface, the evolution with the *measured histograms*, is attempted at every
  level and recorded (``tabulated_evolution``): where the histograms do not nest (seed Eq. 3.1 violated, as study 1
  finds on real surfaces) the library refuses it. The material is rendered in the plugin's closed form (a Gaussian
  lobe: per-scale covariance, exact between the law's scales; ``tolerance=TOLERANCE`` checks it: docs/render.md,
  "Accuracy");
* ``brdfscale_t`` — (d) a non-Gaussian material: ``Beckmann(α0)`` evolved with :class:`MomentStudentTLaw`, per level
  the bivariate Student t with the facets' covariance and the tail index ``ν = 4 + 6/κ`` of their excess kurtosis κ
  (:func:`tail_indices`), on ``T_LADDER`` scales; its Smith masking from Gaussians of LEAN's covariance C(μ)
  (``render.bsdf(masking_shapes=…)``: Λ of an evolved Student-t shape is a slow quadrature). Where its evolution is
  refused at a scale, the study records why (``student_t_material``) and renders the other three.

Errors (relative to the truth's mean radiance, per μ band a factor 2 wide): ``bias`` — |band mean − truth band mean|
(the part a statistical model can remove; sparkle averages out) and ``mean_abs`` — per-pixel mean |Δ| (includes the
sparkle of individual facets that no plane material reproduces). Time to equal error: the micro-geometry rendered at
1, 2, 4, … spp (fresh seeds, kernels compiled beforehand) against the reference; the spp (log-log interpolated) at
which its error equals a plane material's, its measured time there (the ladder's frame times, log-log interpolated:
:func:`ladder_seconds`), and the plane material's shading time — every time the best of ``TIMED_REPEATS`` runs
(sub-millisecond shading calls vary by half their time from run to run).
The *signed* band bias (:func:`signed_bias`, ``diagnosis.signed_bias``) against the truth and against the truth
without its shadow rays says whether shadowing, which no plane material has, would close a material's bias.

Run:  python -m experiments.render_validation [--width 192 --height 128 --size 512 --reference-spp 1024]
Writes experiments/results/render_validation/<surface>.{json,png,exr}.
"""

import argparse
import dataclasses
import math
import os
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np

import brdfscale as bs
from brdfscale import lobes, stats, synth, topography
from experiments import render_plane
from experiments._studies import (
    pixel_slopes,
    save_figure,
    second_moment_covariance,
    study_dir,
    window_slopes,
    write_results,
)


VARIANT = "llvm_ad_rgb"
ALPHA0 = 0.04
CAMERA_HEIGHT = render_plane.CAMERA_HEIGHT / render_plane.TEXEL  # texels
ANISOTROPIC_SLOPE_SCALE = 12.0
REAL_FILE = Path(__file__).resolve().parent.parent / "tests" / "data" / "topographies" / "di-3.di"
SURFACES = ("di-3", "anisotropic")
METHODS = ("naive", "lean", "brdfscale", "brdfscale_t", "empirical")
NU_MAX = 1000.0
T_LADDER = 17  # scales of the Student-t material's ladder (evolved numerically: no refinement)
TOLERANCE = 1e-4  # render.bsdf(tolerance=…) of the Gaussian material (closed form: exact between the law's scales)
LOBE_NODES = 256
EMPIRICAL_NODES = 257
EVOLVE_GRID = 256
MEAN_SLOPE_SAMPLES = 16
RAYS_PER_PASS = 1 << 21
MIN_TILE = 512
TIMED_REPEATS = 3  # every timed render (the micro-geometry ladder, each plane material's shading): the best of these


def mitsuba():
    from brdfscale import _mitsuba

    return _mitsuba.mitsuba(VARIANT)


# -- surfaces ---------------------------------------------------------------------------------------------------


def height_field(name: str, size: int, seed: int = 0) -> synth.HeightField:
    """The periodic ``size``² tile of surface ``name`` in pixel units (spacing 1)."""
    if name == "di-3":
        measured = topography.read(REAL_FILE)
        h = np.asarray(measured.heights) / float(measured.spacing[0])
        half = size // 2
        if half > min(h.shape):
            raise ValueError(f"di-3 has {h.shape} pixels; size {size} needs {half}² of them")
        j0, k0 = (h.shape[0] - half) // 2, (h.shape[1] - half) // 2
        c = h[j0 : j0 + half, k0 : k0 + half]
        tile = np.block([[c, c[:, ::-1]], [c[::-1], c[::-1, ::-1]]])
        desc = {**dict(measured.description), "mirrored_tile": size, "crop": [j0, k0, half]}
        desc.pop("path", None)
        return synth.HeightField(tile - tile.mean(), 1.0, description=desc)
    if name == "anisotropic":
        base = synth.named_surface("anisotropic", size=size, seed=seed)
        return synth.HeightField(
            np.asarray(base.heights) * ANISOTROPIC_SLOPE_SCALE,
            1.0,
            description={**dict(base.description), "slope_scale": ANISOTROPIC_SLOPE_SCALE},
        )
    raise ValueError(f"unknown surface {name!r}; choose from {SURFACES}")


# -- the plane materials per level ----------------------------------------------------------------------------


def level_statistics(field: synth.HeightField, alpha0: float, levels: list[int]) -> dict:
    """Per level b: the facet statistics, the LEAN covariance C(b) and records; the measured scale law (Gaussian
    ``Σ(μ)`` between the levels, :class:`brdfscale.stats.MeasuredScaleLaw`) that the brdfscale material evolves with."""
    facets = synth.facet_statistics(field, levels, bins=129)
    cov1 = np.asarray(facets[0].covariance)
    covs, records = [], []
    for fs in facets:
        covb = np.asarray(fs.covariance)
        cov, clipped = second_moment_covariance(np.eye(2) * alpha0**2 / 2, cov1, covb, alpha0 / 64)
        covs.append(cov)
        w = np.linalg.eigvalsh(cov)
        records.append(
            {
                "level_px": fs.block[1],
                "facets": fs.count,
                "facet_slope_cov": covb.tolist(),
                "lean_cov": cov.tolist(),
                "lean_alpha_uv": [float(math.sqrt(2 * w[1])), float(math.sqrt(2 * w[0]))],
                "lean_clipped": clipped,
            }
        )
    law = stats.MeasuredScaleLaw.from_facets(facets)
    kurtosis, nus = tail_indices(field, levels)
    for record, k, nu in zip(records, kurtosis, nus):
        record.update(excess_kurtosis=k, student_t_nu=nu)
    t_law = MomentStudentTLaw(law, levels, nus)
    return {"law": law, "t_law": t_law, "covs": covs, "records": records, "facets": facets, "field": field}


class MomentStudentTLaw:
    """A non-Gaussian scale law fitted to the facets by moments: at level b, the bivariate Student t
    (:class:`brdfscale.stats.StudentT`) whose covariance ``cov·ν/(ν − 2)`` is the facets' Σ(b) and whose tail index
    ``ν(b) = 4 + 6/κ(b)`` gives the facets' excess kurtosis κ (the mean over Σ's principal axes; ν ≤ NU_MAX). Between
    the levels Σ(μ) is the MeasuredScaleLaw's and 1/ν is linear in ln μ."""

    def __init__(self, gaussian, levels, nus):
        self.gaussian = gaussian
        self.mu = np.asarray(gaussian.mu, float)
        self.levels = np.log(np.asarray(levels, float))
        self.inverse_nu = 1.0 / np.asarray(nus, float)

    def tail_index(self, mu: float) -> float:
        return 1.0 / float(np.interp(math.log(mu), self.levels, self.inverse_nu))

    def at(self, mu):
        nu = self.tail_index(float(mu))
        return stats.StudentT(cov=np.asarray(self.gaussian.slope_covariance(mu)) * (nu - 2) / nu, nu=nu)


def tail_indices(field: synth.HeightField, levels: list[int]) -> tuple[list[float], list[float]]:
    """Excess kurtosis κ(b) of the block-mean facet slopes (mean over their covariance's principal axes) and the
    Student-t tail index ``4 + 6/κ`` of each level (NU_MAX where κ ≤ 6/(NU_MAX − 4))."""
    m = pixel_slopes(np.asarray(field.heights))  # the study's fields are in pixel units (spacing 1)
    kurtosis, nus = [], []
    for b in levels:
        s = window_slopes(m, b, "box").reshape(-1, 2)
        s = s - s.mean(0)
        w, v = np.linalg.eigh(np.cov(s.T))
        z = s @ v / np.sqrt(w)
        k = float(np.mean(np.mean(z**4, axis=0) - 3))
        kurtosis.append(k)
        nus.append(NU_MAX if k <= 6 / (NU_MAX - 4) else 4 + 6 / k)
    return kurtosis, nus


def nesting(field: synth.HeightField, levels: list[int]) -> list[dict]:
    """Whether the pixel slopes nest as the seed's evolution assumes, per level b and axis: the slopes ``m = M_b + r``
    (M_b the block mean, r the deviation within the block, what a footprint's lobe describes). Evolution with
    independent r (seed Eq. 3.1) makes the cumulants add: the variance (exact here for box blocks, law of total
    variance) and the fourth cumulant, so r's excess kurtosis would be ``(κ₄(m) − κ₄(M_b))/var(r)²``; the measured
    one is ``κ₄(r)/var(r)²``. Where they differ the evolved non-Gaussian lobe has the wrong shape."""
    m = pixel_slopes(np.asarray(field.heights))
    out = []
    for b in levels[1:]:
        blocks = window_slopes(m, b, "box")
        mb = np.repeat(np.repeat(blocks, b, axis=0), b, axis=1)
        r = m - mb
        record = {"level_px": b}
        for axis, name in ((0, "x"), (1, "y")):

            def k4(v):
                v = v - v.mean()
                return float(np.mean(v**4) - 3 * np.mean(v**2) ** 2)

            x, big, small = m[..., axis].ravel(), blocks[..., axis].ravel(), r[..., axis].ravel()
            var_r = float(np.var(small))
            record[name] = {
                "variance_sum_check": float(np.var(x) - np.var(big) - var_r),
                "residual_excess_kurtosis": k4(small) / var_r**2,
                "independent_excess_kurtosis": (k4(x) - k4(big)) / var_r**2,
            }
        out.append(record)
    return out


def empirical_table(field: synth.HeightField, alpha0: float, levels: list[int], size: int = EMPIRICAL_NODES):
    """The diagnosis material's lobes: at each level b, Beckmann(α0) convolved with the *measured* distribution of
    the pixel slopes' deviations from their b × b block mean (what a footprint of b texels holds, no nesting assumed;
    b = 1: Beckmann(α0) itself), as a :class:`brdfscale.exr.LobeTable` — a histogram on ``size²`` nodes smoothed by
    the Gaussian of covariance α0²/2·I (scipy.ndimage), over ± the 99.9 % quantile of the deviations plus 4 α0."""
    from scipy import ndimage

    from brdfscale import exr

    m = pixel_slopes(np.asarray(field.heights))
    deviations = []
    for b in levels:
        blocks = window_slopes(m, b, "box")
        deviations.append((m - np.repeat(np.repeat(blocks, b, axis=0), b, axis=1)).reshape(-1, 2))
    extent = max(float(np.quantile(np.abs(r), 0.999)) for r in deviations) + 4 * alpha0
    h = 2 * extent / (size - 1)
    edges = np.linspace(-extent - h / 2, extent + h / 2, size + 1)
    values = []
    for r in deviations:
        counts, _, _ = np.histogram2d(r[:, 1], r[:, 0], bins=[edges, edges])  # rows u_y, columns u_x
        density = ndimage.gaussian_filter(counts, alpha0 / math.sqrt(2) / h, mode="constant") / (len(r) * h * h)
        values.append(density)
    return exr.LobeTable(np.asarray(levels, float), extent, np.asarray(values))


def tabulated_evolution(facets, alpha0: float) -> list[dict]:
    """Whether the Beckmann(α0) lobe evolves with the *tabulated* (measured histogram) statistics from level 1 to
    each level (``brdfscale.evolve(..., regularisation="auto")``): the non-Gaussian material one would want; where
    the measured histograms do not nest (seed Eq. 3.1 violated) the library refuses, and the study records it."""
    out = []
    for fs in facets[1:]:
        try:
            lobe = bs.evolve(
                lobes.Beckmann(alpha0),
                facets[0].slopes,
                fs.slopes,
                method="grid",
                size=EVOLVE_GRID,
                regularisation="auto",
            )
            lobe.density(np.zeros((1, 2)))
            out.append({"level_px": fs.block[1], "exists": True, "why": None})
        except bs.NoBRDFAtScaleError as err:
            out.append({"level_px": fs.block[1], "exists": False, "why": str(err).split(". ")[0]})
    return out


def frame(normals: np.ndarray, angle: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tangent frames (s, t, n) of unit normals (n, 3): s is x projected on the plane ⊥ n, turned by ``angle`` about
    n (radians; the LEAN covariance's eigenvector direction in the slope plane)."""
    ex = np.array([1.0, 0.0, 0.0])
    s = ex - normals[:, :1] * normals
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    t = np.cross(normals, s)
    c, sn = np.cos(angle), np.sin(angle)
    c, sn = np.broadcast_to(c, (len(normals),))[:, None], np.broadcast_to(sn, (len(normals),))[:, None]
    return c * s + sn * t, -sn * s + c * t, normals


def local(vectors: np.ndarray, basis) -> np.ndarray:
    s, t, n = basis
    return np.stack([(vectors * s).sum(1), (vectors * t).sum(1), (vectors * n).sum(1)], axis=1)


def shade(mi, bsdf, wi: np.ndarray, wo: np.ndarray, mu: np.ndarray | None = None) -> np.ndarray:
    """Mitsuba's ``bsdf.eval`` (f·cosθ_wo) at local directions wi (towards the camera) and wo (towards the light),
    both (n, 3); ``mu``: the footprint in texels, given to the BSDF as the uv partials of a unit-texel plane."""
    import drjit as dr

    n = len(wi)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    si.wi = mi.Vector3f(*[drjit_float(mi, wi[:, k]) for k in range(3)])
    if mu is not None:
        m = drjit_float(mi, mu)
        si.dp_du, si.dp_dv = mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0)
        si.duv_dx, si.duv_dy = mi.Vector2f(m, 0.0), mi.Vector2f(0.0, m)
    out = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*[drjit_float(mi, wo[:, k]) for k in range(3)]))
    value = out[0]
    dr.eval(value)
    return np.asarray(value, dtype=float)


ALIGNMENT = 64
"""Bytes: the alignment of the arrays :func:`shade` hands to Dr.Jit."""


def drjit_float(mi, values: np.ndarray):
    """``mi.Float`` of ``values`` (float32) from a copy whose data start on a :data:`ALIGNMENT`-byte boundary.

    On the LLVM variants Dr.Jit reads a NumPy array's own buffer and compiles its kernels with aligned or unaligned
    loads according to whether that buffer starts on a 64-byte boundary, which NumPy's do by chance; with seven such
    inputs per eval, the same eval on fresh arrays often compiled a new kernel (bench_render's frame times, where one
    material's best of three took 28 ms against about 1 ms). Aligned copies give every call the same kernel
    (tests/test_experiments_smoke.py checks the kernels' hashes)."""
    values = np.ascontiguousarray(values, np.float32).ravel()
    buffer = np.empty(values.size + ALIGNMENT // 4, np.float32)
    start = (-buffer.ctypes.data % ALIGNMENT) // 4
    aligned = buffer[start : start + values.size]
    aligned[:] = values
    return mi.Float(aligned)


def roughconductor(mi, alpha_u: float, alpha_v: float | None = None):
    d = {"type": "roughconductor", "distribution": "beckmann", "material": "none"}
    if alpha_v is None:
        d["alpha"] = float(alpha_u)
    else:
        d["alpha_u"], d["alpha_v"] = float(alpha_u), float(alpha_v)
    return mi.load_dict(d)


def alpha_convention_error(mi, alpha_u: float = 0.3, alpha_v: float = 0.1, n: int = 2000, seed: int = 0) -> float:
    """Largest relative difference between Mitsuba's ``roughconductor`` (Beckmann α_u, α_v, no Fresnel, masking
    removed by dividing by Smith's G₁G₁ computed independently) and the Gaussian slope density of per-axis variances
    σ² = α²/2 in brdfscale's ρ = g(m_s)/(4 cosθ_o cos⁴θ_h) — the α² = 2σ² convention the LEAN material relies on.
    Directions: random, both within 60° of the normal, half vectors within 2α of it."""
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(n, 2)) * np.array([alpha_u, alpha_v]) / math.sqrt(2) * 1.5
    hv = np.concatenate([m, np.ones((n, 1))], 1)
    hv /= np.linalg.norm(hv, axis=1, keepdims=True)
    th, ph = np.arccos(rng.uniform(0.5, 1.0, n)), rng.uniform(0, 2 * np.pi, n)
    wi = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], 1)
    wo = 2 * (wi * hv).sum(1, keepdims=True) * hv - wi
    keep = wo[:, 2] > 0.3
    wi, wo, hv, m = wi[keep], wo[keep], hv[keep], m[keep]
    value = shade(mi, roughconductor(mi, alpha_u, alpha_v), wi, wo)
    from scipy.special import erf

    def g1(v):  # Smith G1 of a Beckmann surface, exact (Mitsuba uses a < 0.35 % rational fit)
        a = v[:, 2] / np.sqrt((alpha_u * v[:, 0]) ** 2 + (alpha_v * v[:, 1]) ** 2)
        lam = (erf(a) - 1) / 2 + np.exp(-(a**2)) / (2 * a * math.sqrt(math.pi))
        return 1 / (1 + lam)

    g = np.exp(-(m[:, 0] ** 2) / alpha_u**2 - m[:, 1] ** 2 / alpha_v**2) / (math.pi * alpha_u * alpha_v)
    rho = g / (4 * wi[:, 2] * hv[:, 2] ** 4) * g1(wi) * g1(wo)
    return float(np.max(np.abs(value / rho - 1)))


# -- the micro-geometry ground truth ---------------------------------------------------------------------------


class MicroGeometry:
    """The tiled height-field mesh, a Beckmann-α0 roughconductor on every triangle, study 4's camera and light."""

    def __init__(self, field: synth.HeightField, camera: render_plane.Camera, alpha0: float):
        from brdfscale import instrument

        mi = self.mi = mitsuba()
        repeat = max(1, math.ceil(MIN_TILE / field.heights.shape[0]))
        if repeat > 1:  # a small periodic field repeated into one tile: few instances (their count slows tracing)
            field = synth.HeightField(np.tile(np.asarray(field.heights), (repeat, repeat)), 1.0)
        n = field.heights.shape[0]
        row, col = np.mgrid[0 : camera.height + 1 : camera.height, 0 : camera.width + 1 : camera.width]
        corners, _ = camera.hit(col.astype(float), row.astype(float))
        xy = corners.reshape(-1, 2) / render_plane.TEXEL
        x0, x1 = math.floor(xy[:, 0].min() / n) - 1, math.ceil(xy[:, 0].max() / n) + 1
        y0, y1 = max(math.floor(xy[:, 1].min() / n) - 1, -1), math.ceil(xy[:, 1].max() / n) + 1
        scene = {"type": "scene", "tile": {"type": "shapegroup", "surface": instrument.mesh(field, variant=VARIANT)}}
        for a in range(x0, x1):
            for b in range(y0, y1):
                scene[f"at_{a}_{b}"] = {
                    "type": "instance",
                    "shapegroup": {"type": "ref", "id": "tile"},
                    "to_world": mi.ScalarTransform4f().translate([a * n, b * n, 0.0]),
                }
        self.instances = (x1 - x0) * (y1 - y0)
        self.triangles = 2 * n * n
        self.scene = mi.load_dict(scene)
        self.bsdf = roughconductor(mi, alpha0)
        self.camera = camera
        self.light = np.array(
            [
                0.0,
                math.cos(math.radians(render_plane.LIGHT_ELEVATION_DEG)),
                math.sin(math.radians(render_plane.LIGHT_ELEVATION_DEG)),
            ]
        )

    def _passes(self, spp: int, seed: int):
        """The camera's ``spp`` jittered rays per pixel in passes of at most :data:`RAYS_PER_PASS` rays: yields
        ``(m, si)`` per pass — m rays per pixel, pixel-major, and their first hits (the same rays for the same
        ``spp`` and ``seed``)."""
        import drjit as dr

        mi, cam = self.mi, self.camera
        pixels = cam.width * cam.height
        per_pass = max(1, min(spp, RAYS_PER_PASS // pixels))
        done, k = 0, 0
        while done < spp:
            m = min(per_pass, spp - done)
            idx = dr.arange(mi.UInt32, pixels * m)
            pix = idx // m
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(seed * 1_000_003 + k, pixels * m)
            jitter = sampler.next_2d()
            col = mi.Float(pix % cam.width) + jitter.x
            row = mi.Float(pix // cam.width) + jitter.y
            x = (2 * col / cam.width - 1) * cam.half * cam.width / cam.height
            y = (1 - 2 * row / cam.height) * cam.half
            f, r, u = (mi.Vector3f(*map(float, v)) for v in (cam.forward, cam.right, cam.up))
            d = dr.normalize(f + x * r + y * u)
            yield m, self.scene.ray_intersect(mi.Ray3f(mi.Point3f(0.0, 0.0, CAMERA_HEIGHT), d))
            done += m
            k += 1

    def render(self, spp: int, seed: int, shadows: bool = True) -> tuple[np.ndarray, float]:
        """The mean radiance per pixel over ``spp`` jittered rays, and the wall time (seconds); ``shadows=False``:
        without the shadow ray (every hit lit: the diagnosis of how much the geometry's shadowing weighs)."""
        import drjit as dr

        mi, cam = self.mi, self.camera
        total = np.zeros(cam.width * cam.height)
        started = time.perf_counter()
        for m, si in self._passes(spp, seed):
            light = mi.Vector3f(*map(float, self.light))  # per pass (below: why)
            lit = si.is_valid()
            if shadows:
                lit &= ~self.scene.ray_test(si.spawn_ray(light), si.is_valid())
            value = self.bsdf.eval(mi.BSDFContext(), si, si.to_local(light), lit)[0]
            value = dr.select(lit, value, 0.0)
            sums = dr.block_sum(value, m)
            dr.eval(sums)
            total += np.asarray(sums, dtype=float)
        # one light vector made before the loop was evaluated at the first pass's size and refused by a later pass
        # of another size (Dr.Jit: "operands have incompatible sizes", 192 × 128 px at 256 spp)
        return (total / spp).reshape(cam.height, cam.width), time.perf_counter() - started

    def visible_slopes(self, spp: int, seed: int) -> np.ndarray:
        """Per pixel, the normal slope ``m = (n̄_x/n̄_z, n̄_y/n̄_z)`` (= −∇h, :func:`experiments._studies.pixel_slopes`'
        convention) of the mean unit normal n̄ of the triangles the camera's ``spp`` jittered rays hit (upper side;
        H, W, 2): the micro-geometry's own visibility-weighted normal, where the plane materials take the
        footprint's mean texel slope (:func:`mean_slopes`); experiments/render_visibility.py compares them. The same
        rays as :meth:`render` with the same seed."""
        import drjit as dr

        cam = self.camera
        total = np.zeros((cam.width * cam.height, 3))
        for m, si in self._passes(spp, seed):
            hit = si.is_valid()
            n = dr.select(si.n.z < 0, -si.n, si.n)  # the upper side's normal
            sums = [dr.block_sum(dr.select(hit, v, 0.0), m) for v in (n.x, n.y, n.z)]
            dr.eval(sums)
            total += np.stack([np.asarray(v, float) for v in sums], axis=1)
        z = np.maximum(total[:, 2], 1e-12)
        return np.stack([total[:, 0] / z, total[:, 1] / z], axis=1).reshape(cam.height, cam.width, 2)


# -- the plane renders -------------------------------------------------------------------------------------------


def mean_slopes(field: synth.HeightField, camera, mu: np.ndarray, seed: int) -> np.ndarray:
    """The footprint's mean texel slope per pixel (the ideal mip-mapped normal), (H, W, 2)."""
    slopes = pixel_slopes(np.asarray(field.heights))
    rng = np.random.default_rng(seed)
    out = np.zeros((camera.height, camera.width, 2))
    samples = np.clip(np.ceil(mu), 1, MEAN_SLOPE_SAMPLES).astype(int)
    for r in range(camera.height):
        for s_val in np.unique(samples[r]):
            cols = np.nonzero(samples[r] == s_val)[0]
            grid = (np.arange(s_val)[:, None] + rng.random((cols.size, s_val, s_val, 2))) / s_val
            points, _ = camera.hit(cols[:, None, None] + grid[..., 0], r + np.swapaxes(grid[..., 1], 1, 2))
            out[r, cols] = render_plane.texel_slopes(slopes, points).mean(axis=(1, 2))
    return out


def pixel_geometry(camera, mean_slope: np.ndarray, light: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At each pixel centre (pixel-major, (H·W, 3) each): the view ray, the light direction and the unit normal
    ``(m, 1)/|·|`` of a plane of normal slope ``mean_slope`` (H, W, 2)."""
    row, col = np.mgrid[0 : camera.height, 0 : camera.width] + 0.5
    _, view = camera.hit(col, row)
    view = view.reshape(-1, 3)
    m = mean_slope.reshape(-1, 2)
    normals = np.concatenate([m, np.ones((len(m), 1))], 1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return view, np.broadcast_to(light, view.shape), normals


def plane_directions(camera, mean_slope: np.ndarray, light: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(wi, wo)``: the directions towards the camera and the light in each pixel's plane frame
    (:func:`pixel_geometry`, :func:`frame`), what :func:`shade` takes."""
    view, lights, normals = pixel_geometry(camera, mean_slope, light)
    basis = frame(normals)
    return local(-view, basis), local(lights, basis)


@dataclasses.dataclass
class Scene:
    """Study 8's scene for one surface (:func:`scene`): the tile, camera, per-pixel footprints, levels, their
    statistics and the micro-geometry."""

    field: synth.HeightField
    camera: render_plane.Camera
    mu: np.ndarray
    levels: list[int]
    level_stats: dict
    geometry: "MicroGeometry"


def scene(surface: str, size: int, width: int, height: int, alpha0: float, seed: int = 0) -> Scene:
    """The scene :func:`run` renders (and the diagnoses reuse): ``surface``'s periodic ``size``² tile, study 4's
    camera at ``width`` × ``height``, μ per pixel, the power-of-two levels up to the coarsest footprint (at most
    size/8), their statistics and the meshed micro-geometry."""
    field = height_field(surface, size, seed)
    camera = render_plane.Camera(width, height)
    mu = render_plane.footprints(camera)
    levels = [2**k for k in range(math.ceil(math.log2(max(mu.max(), 2))) + 1) if 2**k <= size // 8]
    statistics = level_statistics(field, alpha0, levels)
    return Scene(field, camera, mu, levels, statistics, MicroGeometry(field, camera, alpha0))


def add_scene_arguments(parser) -> None:
    """The options every study 8 script takes: image, tile, α0, the truth's samples, the surfaces."""
    parser.add_argument("--width", type=int, default=192)
    parser.add_argument("--height", type=int, default=128)
    parser.add_argument("--size", type=int, default=512, help="periodic tile size (texels)")
    parser.add_argument("--alpha0", type=float, default=ALPHA0, help="Beckmann roughness of one texel")
    parser.add_argument("--reference-spp", type=int, default=1024)
    parser.add_argument("--surfaces", nargs="+", default=list(SURFACES), choices=SURFACES)


FAR = 8.0
"""Texels: the footprints the band-bias target is about (μ ≥ 8; bench_render's verdicts)."""


def far_bias(bands: list[dict], key: str) -> float | None:
    """The mean of |signed band bias| (:func:`signed_bias`' ``key``: ``"truth"`` or ``"without_shadow_rays"``) over
    the bands whose lower edge is ≥ :data:`FAR` texels; None where there is none."""
    far = [abs(b[key]) for b in bands if b["mu_band_px"][0] >= FAR]
    return float(np.mean(far)) if far else None


def diagnosis_record(signed: dict, **fields) -> dict:
    """A diagnosis' record of one surface: ``fields`` (its scene and options), the signed band biases per material
    and their :func:`far_bias` against the truth and against the truth without shadow rays."""
    return {
        **fields,
        "signed_bias": signed,
        "far_bias": {
            name: {"truth": far_bias(bands, "truth"), "without_shadow_rays": far_bias(bands, "without_shadow_rays")}
            for name, bands in signed.items()
        },
    }


def diagnosis_main(argv, *, name: str, study: str, run) -> dict:
    """The command line of a study 8 diagnosis (experiments/render_masking.py, render_visibility.py): the scene's
    options and ``--unshadowed-spp``; ``run(surface=…, size=…, width=…, height=…, alpha0=…, reference_spp=…,
    unshadowed_spp=…)`` per surface; ``name`` is ``"<folder>/<file>"``: the script experiments/<folder>.py writes
    ``experiments/results/<folder>/<file>.json`` (or into ``--out``) with the commit and the command."""
    import sys

    from experiments._bench import code_commit

    folder, file = name.split("/")  # the script is experiments/<folder>.py
    parser = argparse.ArgumentParser(description=(sys.modules[run.__module__].__doc__ or study).splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--unshadowed-spp", type=int, default=256, help="study 8's: its ladder's largest spp")
    parser.add_argument("--out", default=None, help=f"output folder (default experiments/results/{folder})")
    args = parser.parse_args(argv)
    options = dict(width=args.width, height=args.height, size=args.size, alpha0=args.alpha0)
    spp = dict(reference_spp=args.reference_spp, unshadowed_spp=args.unshadowed_spp)
    payload = {
        "study": study,
        "code_commit": code_commit(),
        "command": " ".join([f"python -m experiments.{folder}", *(sys.argv[1:] if argv is None else argv)]),
        "surfaces": {s: run(surface=s, **options, **spp) for s in args.surfaces},
    }
    write_results(study_dir(folder, args.out), file, payload)
    return payload


def level_weights(mu: np.ndarray, levels: list[int]) -> np.ndarray:
    """Weights (len(levels), …) of linear interpolation in log₂ μ between the levels (clamped at the ends)."""
    pos = np.clip(np.log2(np.maximum(mu, 1.0)), 0, len(levels) - 1)
    lo = np.minimum(np.floor(pos).astype(int), max(len(levels) - 2, 0))
    w = pos - lo
    return np.stack([np.where(lo == k, 1 - w, 0.0) + np.where(lo + 1 == k, w, 0.0) for k in range(len(levels))])


def render_planes(
    mi, camera, mu, mean_slope, light, level_stats, levels, alpha0, masking=True, repeat: int = 1
) -> tuple[dict, dict]:
    """The plane materials shaded once per pixel centre; images and shading seconds per method (the best of
    ``repeat`` timed runs after a compiling one)."""
    from brdfscale import render

    view, lights, normals = pixel_geometry(camera, mean_slope, light)
    mus = mu.ravel()
    weights = level_weights(mus, levels)
    images, seconds = {}, {}

    def best(name, run):
        """``images[name] = run()`` and ``seconds[name]``: its best wall time over ``repeat`` runs after a compiling
        one."""
        run()
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            images[name] = run()
            times.append(time.perf_counter() - t0)
        seconds[name] = min(times)

    basis = frame(normals)
    wi, wo = local(-view, basis), local(lights, basis)
    naive = roughconductor(mi, alpha0)
    best("naive", lambda: shade(mi, naive, wi, wo))

    lean = []
    for cov in level_stats["covs"]:
        w, v = np.linalg.eigh(cov)
        lean.append((roughconductor(mi, math.sqrt(2 * w[1]), math.sqrt(2 * w[0])), math.atan2(v[1, 1], v[0, 1])))

    per_level = []  # the pixels of each level and their directions in its frame, made before the timed runs
    for k, (material, angle) in enumerate(lean):
        sel = weights[k] > 0
        if np.any(sel):
            b = frame(normals[sel], angle)
            per_level.append((material, sel, weights[k][sel], local(-view[sel], b), local(lights[sel], b)))

    def lean_image():
        out = np.zeros(len(view))
        for material, sel, weight, wi_level, wo_level in per_level:
            out[sel] += weight * shade(mi, material, wi_level, wo_level)
        return out

    best("lean", lean_image)

    def timed(name, material):
        """Shade every pixel with ``material`` at its footprint: image and seconds."""
        best(name, lambda: shade(mi, material, wi, wo, mus))

    def material(law, **options):
        """``render.bsdf`` of the base lobe Beckmann(α0) at μ0 = 1 texel evolved with ``law``."""
        return render.bsdf(
            lobes.Beckmann(alpha0),
            law,
            mu0=1.0,
            texel=1.0,
            size=LOBE_NODES,
            masking=masking,
            variant=VARIANT,
            **options,
        )

    timed("brdfscale", material(level_stats["law"], tolerance=TOLERANCE))

    # the non-Gaussian material: Beckmann(α0) evolved with the moment-matched Student-t law; its masking tables from
    # Gaussians of the same covariance (LEAN's), as Smith Λ of an evolved Student-t shape is a slow quadrature
    law = level_stats["law"]
    ladder = [float(x) for x in np.geomspace(1.0, levels[-1], T_LADDER)]
    gaussians = [
        stats.Gaussian(
            cov=np.eye(2) * alpha0**2 / 2 + np.asarray(law.slope_covariance(1.0)) - np.asarray(law.slope_covariance(m))
        )
        for m in ladder
    ]
    try:
        material_t = material(level_stats["t_law"], scales=ladder, masking_shapes=gaussians)
    except bs.NoBRDFAtScaleError as err:
        level_stats["t_refused"] = str(err).split(". ")[0]
    else:
        timed("brdfscale_t", material_t)

    # the diagnosis material: the measured within-footprint slope distributions (no evolution), masked like (d)
    table = empirical_table(level_stats["field"], alpha0, levels)
    timed(
        "empirical",
        render.bsdf(
            None,
            table,
            texel=1.0,
            masking=masking,
            variant=VARIANT,
            masking_shapes=[stats.Gaussian(cov=np.asarray(c)) for c in level_stats["covs"]],
        ),
    )
    return {k: v.reshape(mu.shape) for k, v in images.items()}, seconds


# -- errors ----------------------------------------------------------------------------------------------------


def bands_of(mu: np.ndarray) -> np.ndarray:
    return np.floor(np.log2(np.maximum(mu, 1.0))).astype(int)


def band_errors(image: np.ndarray, truth: np.ndarray, mu: np.ndarray) -> list[dict]:
    scale = truth.mean()
    bands = bands_of(mu)
    out = []
    for b in np.unique(bands):
        sel = bands == b
        out.append(
            {
                "mu_band_px": [2.0**b, 2.0 ** (b + 1)],
                "pixels": int(sel.sum()),
                "bias": float(abs(image[sel].mean() - truth[sel].mean()) / scale),
                "mean_abs": float(np.abs(image[sel] - truth[sel]).mean() / scale),
            }
        )
    return out


def summary_errors(image, truth, mu, threshold: float = 8.0) -> dict:
    """Errors over all pixels and over those with μ ≥ ``threshold`` texels (the target's region)."""
    scale = truth.mean()
    sel = mu >= threshold
    far = {}
    if np.any(sel):
        bands = bands_of(mu)
        far = {
            "bias_mean_over_bands": float(
                np.mean(
                    [
                        abs(image[sel & (bands == b)].mean() - truth[sel & (bands == b)].mean())
                        for b in np.unique(bands[sel])
                    ]
                )
                / scale
            ),
            "mean_abs": float(np.abs(image[sel] - truth[sel]).mean() / scale),
        }
    return {
        "mean_abs": float(np.abs(image - truth).mean() / scale),
        "rms": float(np.sqrt(np.mean((image - truth) ** 2)) / scale),
        "mu_ge_threshold": far,
        "bands": band_errors(image, truth, mu),
    }


def shadowing(truth: np.ndarray, unshadowed: np.ndarray, mu: np.ndarray) -> list[dict]:
    """Per μ band: the truth's band mean without and with the micro-geometry's shadow rays (relative to the truth's
    mean): the part of the truth that no plane material models (none shadows one footprint by another)."""
    scale = truth.mean()
    bands = bands_of(mu)
    return [
        {
            "mu_band_px": [2.0**b, 2.0 ** (b + 1)],
            "truth": float(truth[bands == b].mean() / scale),
            "without_shadow_rays": float(unshadowed[bands == b].mean() / scale),
        }
        for b in np.unique(bands)
    ]


def signed_bias(images: dict, truth: np.ndarray, unshadowed: np.ndarray, mu: np.ndarray) -> dict:
    """Per material and μ band, the *signed* band bias (band mean − the truth's band mean, ÷ the truth's mean; the
    ``bias`` of :func:`band_errors` is its absolute value) against the truth and against the truth without its
    shadow rays: whether shadowing that no plane material has would close a material's bias (it darkens every
    band, so it can only close a bias of the material's brightness)."""
    scale = truth.mean()
    bands = bands_of(mu)
    return {
        m: [
            {
                "mu_band_px": [2.0**b, 2.0 ** (b + 1)],
                "truth": float((image[bands == b].mean() - truth[bands == b].mean()) / scale),
                "without_shadow_rays": float((image[bands == b].mean() - unshadowed[bands == b].mean()) / scale),
            }
            for b in np.unique(bands)
        ]
        for m, image in images.items()
    }


def ladder_seconds(ladder: list[dict], spp: float) -> float:
    """The micro-geometry's measured wall time at ``spp`` samples per pixel: log-log interpolation of the ladder's
    timed renders (each a full frame with its passes and transfers), the smallest spp's time below it."""
    counts = np.array([x["spp"] for x in ladder], float)
    seconds = np.array([x["seconds"] for x in ladder], float)
    return float(np.exp(np.interp(math.log(max(spp, counts[0])), np.log(counts), np.log(seconds))))


def equal_error_spp(ladder: list[dict], target: float, key: str) -> float | None:
    """The spp at which the micro-geometry's error ``key`` falls to ``target`` (log-log interpolation along the
    ladder; None when even the largest spp is above it; the smallest spp when already below)."""
    spp = np.array([x["spp"] for x in ladder], float)
    err = np.array([x[key] for x in ladder], float)
    if err[0] <= target:
        return float(spp[0])
    for k in range(1, len(spp)):
        if err[k] <= target:
            a = (math.log(target) - math.log(err[k - 1])) / (math.log(err[k]) - math.log(err[k - 1]))
            return float(math.exp(math.log(spp[k - 1]) + a * (math.log(spp[k]) - math.log(spp[k - 1]))))
    return None


# -- the study -------------------------------------------------------------------------------------------------


def run(
    *,
    surface: str,
    size: int,
    width: int,
    height: int,
    alpha0: float = ALPHA0,
    reference_spp: int,
    ladder_spp: list[int],
    seed: int = 0,
    out=None,
    figures: bool = True,
    check_tabulated: bool = True,
    masking: bool = True,
) -> dict:
    load = os.getloadavg()[0]  # the machine's load before the study's timed renders (recorded: times depend on it)
    directory = study_dir("render_validation", out)
    mi = mitsuba()
    setup = scene(surface, size, width, height, alpha0, seed)
    field, camera, mu, levels = setup.field, setup.camera, setup.mu, setup.levels
    level_stats, geometry = setup.level_stats, setup.geometry
    tabulated = tabulated_evolution(level_stats["facets"], alpha0) if check_tabulated else None
    for spp in (reference_spp, *ladder_spp):  # compile every kernel first (Dr.Jit compiles one per pass size)
        geometry.render(spp, seed + 99)
    truth, truth_seconds = geometry.render(reference_spp, seed + 1)
    unshadowed, _ = geometry.render(max(ladder_spp), seed + 1, shadows=False)
    ladder = []
    for k, spp in enumerate(ladder_spp):
        image, seconds = geometry.render(spp, seed + 1000 + k)
        for _ in range(TIMED_REPEATS - 1):  # the same seed renders the same image: only its time varies
            seconds = min(seconds, geometry.render(spp, seed + 1000 + k)[1])
        e = summary_errors(image, truth, mu)
        ladder.append(
            {
                "spp": spp,
                "seconds": seconds,
                "mean_abs": e["mean_abs"],
                "far_mean_abs": e["mu_ge_threshold"].get("mean_abs"),
                "far_bias": e["mu_ge_threshold"].get("bias_mean_over_bands"),
            }
        )
    slopes = mean_slopes(field, camera, mu, seed + 2)
    images, seconds = render_planes(
        mi, camera, mu, slopes, geometry.light, level_stats, levels, alpha0, masking, repeat=TIMED_REPEATS
    )
    methods = [m for m in METHODS if m in images]
    errors = {m: summary_errors(images[m], truth, mu) for m in methods}
    equal = {}
    for m in methods:
        entry = {"shading_seconds": seconds[m]}
        for key, name in (("mean_abs", "mean_abs"), ("far_mean_abs", "mean_abs"), ("far_bias", "bias_mean_over_bands")):
            target = errors[m]["mean_abs"] if key == "mean_abs" else errors[m]["mu_ge_threshold"].get(name)
            spp_eq = None if target is None else equal_error_spp(ladder, target, key)
            entry[key] = {
                "error": target,
                "micro_geometry_spp": spp_eq,
                "micro_geometry_seconds": None if spp_eq is None else ladder_seconds(ladder, spp_eq),
                "speedup": None if spp_eq is None else ladder_seconds(ladder, spp_eq) / seconds[m],
            }
        equal[m] = entry
    all_images = {"truth": truth, **images, "mu": mu}
    render_plane.write_exr(directory / f"{surface}.exr", all_images)
    payload = {
        "study": "render validation on micro-geometry: plane receding from near to far",
        "surface": surface,
        "surface_description": {k: v for k, v in dict(field.description).items() if k != "trend"},
        "tile_size": size,
        "image": [width, height],
        "alpha0": alpha0,
        "variant": VARIANT,
        "brdfscale_masking": masking,
        "camera_height_texels": CAMERA_HEIGHT,
        "pitch_deg": render_plane.PITCH_DEG,
        "vfov_deg": render_plane.VFOV_DEG,
        "light_elevation_deg": render_plane.LIGHT_ELEVATION_DEG,
        "mu_range_px": [float(mu.min()), float(mu.max())],
        "levels_px": levels,
        "levels": level_stats["records"],
        "tabulated_evolution": tabulated,
        "student_t_material": level_stats.get("t_refused", "rendered"),
        "instances": geometry.instances,
        "triangles_per_tile": geometry.triangles,
        "reference_spp": reference_spp,
        "reference_seconds": truth_seconds,
        "load_average_at_start": load,
        "micro_geometry_ladder": ladder,
        "errors": errors,
        "equal_error": equal,
        "alpha_convention_max_relative_error": alpha_convention_error(mi),
        "diagnosis": {
            "shadowing": shadowing(truth, unshadowed, mu),
            "signed_bias": signed_bias({m: images[m] for m in methods}, truth, unshadowed, mu),
            "nesting": nesting(field, levels),
            "model_spread_mu_ge_8": float(
                np.std([errors[m]["mu_ge_threshold"]["bias_mean_over_bands"] for m in methods if m != "naive"])
            ),
        },
    }
    write_results(directory, surface, payload)
    if figures:
        plot(all_images, errors, directory / f"{surface}.png", surface)
    return payload


def plot(images: dict, errors: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    top = np.percentile(images["truth"], 99.5)
    methods = [m for m in METHODS if m in images]
    names = ("truth", *methods)
    fig, axes = plt.subplots(2, len(names), figsize=(4 * len(names), 6.2))
    for ax, name in zip(axes[0], names):
        ax.imshow(np.clip(images[name] / top, 0, 1) ** (1 / 2.2), cmap="gray", vmin=0, vmax=1)
        label = "micro-geometry (truth)" if name == "truth" else f"{name} (mean |Δ| {errors[name]['mean_abs']:.2f})"
        ax.set_title(label)
    axes[1, 0].imshow(np.log2(np.maximum(images["mu"], 0.5)), cmap="viridis")
    axes[1, 0].set_title("log₂ footprint μ [texels]")
    for ax, name in zip(axes[1, 1:], methods):
        ax.imshow(np.abs(images[name] - images["truth"]) / top, cmap="magma", vmin=0, vmax=0.5)
        ax.set_title(f"|{name} − truth|")
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(title)
    save_figure(fig, path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--ladder-spp", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64, 128, 256])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="output folder (default experiments/results/render_validation)")
    args = parser.parse_args(argv)
    for surface in args.surfaces:
        run(
            surface=surface,
            size=args.size,
            width=args.width,
            height=args.height,
            alpha0=args.alpha0,
            reference_spp=args.reference_spp,
            ladder_spp=args.ladder_spp,
            seed=args.seed,
            out=args.out,
        )


if __name__ == "__main__":
    main()
