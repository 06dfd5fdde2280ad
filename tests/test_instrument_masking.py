"""Issue 32 item 3 (the part that needs masking): the ray-traced instrument's macro-BRDF of a Beckmann or GGX surface
equals the microfacet model with Smith masking of α_eff, within the instrument's Monte Carlo error plus the stated
nearly-flat term.

The surface: a nearly flat Gaussian height field (rms pixel slope ``ALPHA_GEO``) whose pixel facets are Beckmann or
GGX micro-surfaces of roughness ``ALPHA_MICRO`` (Mitsuba's ``roughconductor``: its own masking is Smith's
uncorrelated ``G₁(i)·G₁(o)``, Walter et al. 2007). Measured at the spot that holds the whole field, the image is
``g(u) = P₂₂(u)·G(i, o(u))`` (the measurement convention ``g = 4 cosθ_o cos⁴θ_h ρ``, ``ρ`` the seed's ``f_r cosθ_i``),
with ``P₂₂`` the micro-slope density convolved with the pixel-slope density — which is exactly
:func:`brdfscale.synth.gonioreflectometer`'s image of the same field (α_eff² = α_geo² + α_micro² for Beckmann) — and
``G`` Smith's masking of that density (:class:`brdfscale.lobes.SmithMasking` with ``correlated=False``), as the
detector records it (its nearest-node binning: :func:`_binned`).

Error budget of the comparison: the instrument's σ (its Monte Carlo standard error, per pixel and of the image's
sum); the nearly-flat term of the geometric facets, of order ``ALPHA_GEO²`` (4·10⁻⁴ here: the seed's error grows like
α² of the facets it treats as flat); Mitsuba's rational approximation of Beckmann's G₁ (< 0.35 % per factor; its GGX
G₁ is exact). The unmasked model must miss by more than that budget at grazing incidence, so that the test can fail.
"""

import math

import numpy as np
import pytest

from brdfscale import lobes, stats, synth


pytest.importorskip("mitsuba")
instrument = pytest.importorskip("brdfscale.instrument")

ALPHA_GEO, ALPHA_MICRO = 0.02, 0.3


def _g1_approximation(micro) -> float:
    """Mitsuba's Beckmann G₁ is a rational approximation within 0.35 % (two factors); its GGX G₁ is exact."""
    return 0.0 if isinstance(micro, stats.GGX) else 2 * 0.0035  # stats.Beckmann(α) is a stats.Gaussian


def _field(size: int, micro) -> synth.HeightField:
    base = synth.spectral_field(stats.GaussianCorrelation(1.0, 6.0), size=size, seed=4)
    h = np.asarray(base.heights)
    mx, my = np.roll(h, -1, axis=1) - h, np.roll(h, -1, axis=0) - h
    scale = ALPHA_GEO / math.sqrt(np.mean(mx**2 + my**2))
    return synth.HeightField(h * scale, 1.0, micro=micro)


def _outgoing(i: np.ndarray, u: np.ndarray) -> np.ndarray:
    n = np.concatenate([u, np.ones(u.shape[:-1] + (1,))], axis=-1)  # n ∝ (m, 1) for a facet of normal slope m
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return 2 * (n @ i)[..., None] * n - i


def _binned(g: np.ndarray) -> np.ndarray:
    """The model as the detector records it: light counted in the node whose cell holds it (the instrument's default
    ``binning="nearest"``) is the density averaged over the pixel cell, ``g + (h²/24)∇²g`` to second order in the
    pitch h — per axis the kernel ``[1, 22, 1]/24`` on the nodes (zero beyond the grid)."""
    k = np.array([1.0, 22.0, 1.0]) / 24
    rows = np.apply_along_axis(lambda r: np.convolve(r, k, mode="same"), 1, g)
    return np.apply_along_axis(lambda c: np.convolve(c, k, mode="same"), 0, rows)


def _compare(micro, *, size, thetas, rays, pixels=33, surface="pixel_facets"):
    field = _field(size, micro)
    extent = 4 * ALPHA_MICRO / math.sqrt(2)  # ±4 σ per axis of the micro lobe
    incident = np.array([[math.sin(math.radians(t)), 0.0, math.cos(math.radians(t))] for t in thetas])
    measured = instrument.measure(
        field,
        [float(size)],
        incident,
        extent=extent,
        pixels=pixels,
        rays=rays,
        bounces=1,
        seed=7,
        surface=surface,
        progress=False,
    )
    seed_model = synth.gonioreflectometer(field, [float(size)], incident, extent=extent, pixels=pixels)
    x = np.linspace(-extent, extent, pixels)
    u = np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)
    masking = lobes.SmithMasking(correlated=False)
    out = []
    for image, flat in zip(measured.images, seed_model.images, strict=True):
        i = np.asarray(image.incident, dtype=float)
        o = _outgoing(i, u)
        above = o[..., 2] > 1e-9
        o = np.where(above[..., None], o, [0.0, 0.0, 1.0])
        g = np.where(above, np.asarray(masking.g2(micro, np.broadcast_to(i, o.shape), o)), 0.0)
        g_inst, sigma = np.asarray(image.values, float), np.asarray(image.sigma, float)
        unmasked = np.where(above, np.asarray(flat.values, float), 0.0)
        # the detector deposits light bilinearly onto the nodes (cloud in cell): a node within one pitch of the
        # horizon collects light from beyond it, where the model is 0; those nodes are left out of the pixel test
        padded = np.pad(above, 1, constant_values=True)
        inner = above & padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:]
        inner[[0, -1], :] = inner[:, [0, -1]] = False  # the grid's border nodes collect from half a cell only
        out.append((g_inst, sigma, _binned(unmasked * g), _binned(unmasked), inner))
    return out


def _check(results, thetas, micro):
    g1 = _g1_approximation(micro)
    for theta, (g_inst, sigma, masked, unmasked, inner) in zip(thetas, results, strict=True):
        total = g_inst.sum()
        mc = math.sqrt((sigma**2).sum()) / total
        budget = 3 * mc + ALPHA_GEO**2 + g1
        assert abs(masked.sum() / total - 1) <= budget, (theta, masked.sum() / total, budget)
        chi2 = np.mean(((g_inst - masked) ** 2 / (sigma**2 + (g1 * masked) ** 2))[inner])
        assert chi2 < 2.0, (theta, chi2)
        if theta >= 70:  # where masking matters, the seed's model (G = 1) is outside the same budget
            assert unmasked.sum() / total - 1 > 2 * budget, (theta, unmasked.sum() / total, budget)


@pytest.mark.parametrize(
    "micro",
    [stats.Beckmann(ALPHA_MICRO), pytest.param(stats.GGX(ALPHA_MICRO), marks=pytest.mark.slow)],
    ids=["beckmann", "ggx"],
)
def test_smith_masking_matches_the_instrument_at_grazing_incidence(micro):
    """The tiny default version: a 32² field, one incidence (75°), 4·10⁴ rays (GGX in the slow suite)."""
    _check(_compare(micro, size=32, thetas=[75.0], rays=40_000), [75.0], micro)


@pytest.mark.slow  # ~15 s each on 2 cores: 5 incidences × 2·10⁵ rays
def test_smith_masking_matches_the_instrument_up_to_80_degrees_beckmann():
    thetas = [0.0, 40.0, 60.0, 70.0, 80.0]
    _check(
        _compare(stats.Beckmann(ALPHA_MICRO), size=128, thetas=thetas, rays=200_000),
        thetas,
        stats.Beckmann(ALPHA_MICRO),
    )


@pytest.mark.slow
def test_smith_masking_matches_the_instrument_up_to_70_degrees_ggx():
    thetas = [0.0, 40.0, 60.0, 70.0]
    _check(_compare(stats.GGX(ALPHA_MICRO), size=128, thetas=thetas, rays=200_000), thetas, stats.GGX(ALPHA_MICRO))


@pytest.mark.slow
@pytest.mark.parametrize("surface, passes", [("triangles", True), ("pixel_facets", False)])
def test_smith_masking_matches_the_instrument_at_80_degrees_ggx(surface, passes):
    """At 80° on GGX micro-facets the pixel-facet mesh's vertical slivers intercept grazing light the model does not
    hold (the model's energy 0.95 % above the instrument's, against a budget of 0.87 %: 3 MC errors + α_geo²); on
    the continuous triangulated surface the same comparison is within 0.51 % (docs/results.md §7: the slivers grow
    with the slopes' mixed second differences and tan θ_i)."""
    results = _compare(stats.GGX(ALPHA_MICRO), size=128, thetas=[80.0], rays=200_000, surface=surface)
    if passes:
        _check(results, [80.0], stats.GGX(ALPHA_MICRO))
    else:
        with pytest.raises(AssertionError):
            _check(results, [80.0], stats.GGX(ALPHA_MICRO))
