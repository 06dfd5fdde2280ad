"""The fits on instrument data (issue 32 item 6; experiments/instrument_fits.py, docs/instrument.md "Fits of
instrument data").

The masking claim on the shipped ray-traced di-3 set (no ray tracing). The study script's own parts — its truths
against closed forms and the library's facet statistics, its noise statistic against binned random points, its
scores by hand, and the claim on a small measurement made with the instrument (slow) — are tested in
tests/test_experiments_smoke.py, the one test module that imports experiments/.
"""

import math
from pathlib import Path

import numpy as np

from brdfscale import exr, lobes
from brdfscale.fitting._masking import masking_factors


DATA = Path(__file__).resolve().parent / "data" / "instrument"


# -- the claim on the shipped ray-traced set (no ray tracing) ------------------------------------------------


def _moments(values, sigma, extent):
    """Energy, mean and variance along x of an image's lobe, each with its standard error from σ (linear, pixels
    independent, as the instrument's nearest-node binning makes them; each margin below is in units of twice the
    standard error all the same)."""
    n = values.shape[0]
    x = np.linspace(-extent, extent, n)
    ux = np.broadcast_to(x, (n, n))
    total = values.sum()
    mean = (values * ux).sum() / total
    var = (values * (ux - mean) ** 2).sum() / total
    h2 = (2 * extent / (n - 1)) ** 2
    return {
        "energy": (total * h2, np.sqrt((sigma**2).sum()) * h2),
        "mean_x": (mean, np.sqrt((((ux - mean) / total * sigma) ** 2).sum())),
        "var_x": (var, np.sqrt(((((ux - mean) ** 2 - var) / total * sigma) ** 2).sum())),
    }


def test_smith_masking_reduces_but_does_not_remove_the_grazing_bias_of_the_shipped_di3_set():
    """The ray-traced AFM file di-3 at its coarsest scale, 0° and 70° incidence (tests/data/instrument): the light
    at 70° is masked and shadowed — less energy, a lobe shifted and narrowed along the incidence plane. Dividing out
    Smith's G₂ (fitting's forward model, Dataset.from_measurements(masking="smith")) moves each of the three towards
    the 0° image by many standard errors, yet leaves each short of it by many: the light reflected more than once or
    below the horizon is not in Smith's G₂ (docs/masking.md)."""
    mset = exr.read_measurements(str(DATA / "di-3_raytraced.exr"))
    coarsest = max(image.mu for image in mset.images)
    images = sorted((p for p in mset.images if p.mu == coarsest), key=lambda p: -p.incident[2])
    values = [np.asarray(p.values) for p in images]
    factors = masking_factors(lobes.SmithMasking(), images, values, [np.ones(v.shape, bool) for v in values])
    normal = _moments(values[0], np.asarray(images[0].sigma), images[0].extent)
    grazing = _moments(values[1], np.asarray(images[1].sigma), images[1].extent)
    keep = factors[1] > 0
    g = np.where(keep, factors[1], 1.0)
    unmasked = np.where(keep, values[1] / g, 0.0), np.where(keep, np.asarray(images[1].sigma) / g, 0.0)
    smith = _moments(*unmasked, images[1].extent)
    assert math.isclose(math.degrees(math.acos(images[1].incident[2])), 70.0, abs_tol=1e-6)
    for name in ("energy", "mean_x", "var_x"):
        (n0, e0), (raw, e1), (corrected, e2) = normal[name], grazing[name], smith[name]
        moved, left = abs(corrected - raw), abs(n0 - corrected)
        assert abs(n0 - raw) > 10 * 2 * math.hypot(e0, e1), name  # the grazing bias: far beyond the MC error
        assert moved > 3 * 2 * math.hypot(e1, e2), name  # masking moves towards normal incidence ...
        assert left < abs(n0 - raw), name
        assert left > 5 * 2 * math.hypot(e0, e2), name  # ... but does not get there
