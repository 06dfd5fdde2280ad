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
    for image in mset.images:
        values, sigma = np.asarray(image.values), np.asarray(image.sigma)
        assert values.shape == sigma.shape == (33, 33)
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
