"""The shipped instrument measurement sets (tests/data/instrument/, issue 32 item 7): read and fitted without Mitsuba.

Each file is what its README's command wrote (its metadata records that command); reading it and fitting it
needs no ray tracer, which the fit test proves by making Mitsuba unimportable first.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from brdfscale import exr
from brdfscale._cli import main


DATA = Path(__file__).resolve().parent / "data" / "instrument"
FILES = ("di-3_raytraced.exr", "anisotropic_ggx_raytraced.exr")


@pytest.mark.parametrize("name", FILES)
def test_shipped_set_is_small_read_with_its_provenance(name):
    path = DATA / name
    assert path.stat().st_size <= 200_000
    mset = exr.read_measurements(str(path))
    meta = mset.metadata
    assert meta["instrument"]["type"] == "raytraced" and meta["generator"] == "brdfscale.instrument.measure"
    block = (DATA / "README.md").read_text().split("```")[1]  # the generating commands
    readme = " ".join(block.replace("\\\n", " ").split())
    # the README's generating command is the one the file records (the recorded one names the options it was given)
    recorded = meta["command"].split()
    command = next(line for line in readme.split("brdfscale synth")[1:] if name in line)
    for token in recorded[2:]:
        assert token in command.split() or token.startswith("--detrend") or token == "plane", (token, command)
    assert len(mset.images) == 6
    pixels = meta["pixels"]
    for image in mset.images:
        values, sigma = np.asarray(image.values), np.asarray(image.sigma)
        assert values.shape == sigma.shape == (pixels, pixels) and pixels >= 33
        assert np.all(np.isfinite(values)) and np.all(values >= 0) and np.all(sigma > 0)
        # a Monte Carlo error: small where much light fell, relative to the image's peak
        assert sigma[np.unravel_index(np.argmax(values), values.shape)] < 0.2 * values.max()


@pytest.mark.slow  # one fit of the default model (≈ 15 s of CPU, a minute on a loaded machine)
@pytest.mark.parametrize("masking", ["none", "smith"])
def test_shipped_set_is_fitted_without_ray_tracing(tmp_path, monkeypatch, capsys, masking):
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # no ray tracer: `import mitsuba` fails
    out = tmp_path / "fit"
    argv = ["fit", str(DATA / FILES[0]), "--out", str(out), "--steps", "0", "--starts", "1", "--no-progress"]
    code = main([*argv, "--masking", masking])
    doc = json.loads((out / "fit.json").read_text())
    # the exit status is the report's verdict (di-3's heavy-tailed lobes are not Gaussian: inadequate is honest)
    assert code == {"ok": 0, "inadequate": 5, "not_converged": 6}[doc["outcome"]["status"]]
    assert doc["optimisation"]["status"] == "converged"
    amplitude = doc["parameters"]["amplitude"]["estimate_map"]
    # mirror facets reflect all light; what reaches the 33² px grid of the images is the amplitude's scale
    assert 0.5 < amplitude < 1.2
    assert "mitsuba" not in capsys.readouterr().err.lower()


def _light_and_variance(image, record):
    """The share of an image's detected light that lies on its nodes, and the lobe's variance along x.

    A detected path of weight w adds w·c/(N h²) to its node, c = i_z/(i_z + u·i_xy) (docs/instrument.md, "The
    conventions"), so Σ values·h²/c over the nodes is the weight per lit ray that fell on the image; the record's
    ``detected_fraction`` is the weight per lit ray of every path leaving above the spot's plane."""
    values = np.asarray(image.values, dtype=np.float64)
    n, a = values.shape[0], image.extent
    x = np.linspace(-a, a, n)
    ux, uy = np.meshgrid(x, x)  # rows u_y
    i = np.asarray(image.incident, dtype=np.float64)
    c = i[2] / (i[2] + ux * i[0] + uy * i[1])
    light = float((values / c).sum() * (2 * a / (n - 1)) ** 2 / record["detected_fraction"])
    w = values / values.sum()
    mean = (w * ux).sum()
    return light, float((w * (ux - mean) ** 2).sum())


def test_shipped_ggx_set_holds_its_light_and_shows_the_scale_evolution():
    """The GGX set's images hold ≥ 95 % of the detected light (98.4–98.8 %; the earlier file's extent, the default
    that counts the pixel slopes but not the micro-facets' GGX tails, held 23 %), and its scales straddle the
    surface's correlation lengths (6 × 24 px): the spots' facet-slope covariance Σ_xx(μ) (the metadata's truth)
    falls 79-fold from the first scale (2 px) to the last (32 px), and the lobes widen by what it loses — the
    images' variance along x grows 3.4-fold, by Σ_xx(2) − Σ_xx(32) within 6 % (the seed's ΔΣ, Eq. 4.4; the GGX
    tails cut at the image's edge take the rest; the earlier file's variance was the same at every scale, that of
    light spread over its whole image)."""
    mset = exr.read_measurements(str(DATA / FILES[1]))
    meta = mset.metadata
    records = meta["instrument"]["images"]
    assert len(records) == len(mset.images)
    found = {}
    for image, record in zip(mset.images, records):
        assert record["mu"] == image.mu and np.allclose(record["incident"], image.incident)
        light, var = _light_and_variance(image, record)
        assert light >= 0.95, (image.mu, image.incident, light)
        found[(image.mu, tuple(np.round(image.incident, 6)))] = var
    scales = sorted(meta["scales"])
    sigma_xx = {mu: cov[0][0] for mu, cov in zip(meta["scales"], meta["truth"]["facet_slope_covariance"])}
    assert sigma_xx[scales[0]] / sigma_xx[scales[-1]] >= 50  # 79
    drop = sigma_xx[scales[0]] - sigma_xx[scales[-1]]
    incidences = {key[1] for key in found}
    assert len(incidences) == 2  # 0° and 60°
    for incident in incidences:
        first, last = found[(scales[0], incident)], found[(scales[-1], incident)]
        assert last / first >= 3.0, (incident, last / first)  # 3.4 at both incidences
        assert abs((last - first) / drop - 1) <= 0.1, (incident, (last - first) / drop)  # −5.5 %, −5.7 %
