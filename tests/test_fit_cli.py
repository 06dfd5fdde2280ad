"""The non-parametric model through the ``brdfscale fit`` command on a small synthetic file.

This is a test of the command's path (options, model, fit, report, tables), kept fast with a
coarse model (7 × 7 base nodes, 3 knots, 40 solver steps) that need not converge: the report
must then say so. Recovery by the non-parametric model is tests/test_fit_slow.py's job.
"""

import json

import numpy as np
import pytest

from brdfscale import exr, fitting
from brdfscale._cli import main


TRUTH = dict(amplitude=0.8, alpha_lobe=0.06, alpha_max=0.2, mu_c=1.0, exponent=0.8)
SCALES = (0.5, 2.0, 8.0)


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_nonparametric_fit_command(tmp_path, capsys):
    mset = fitting.simulate(
        fitting.ParametricModel(), TRUTH, SCALES, size=12, extent=0.35, noise=0.01, floor=1e-3, seed=2
    )
    path = tmp_path / "m.exr"
    exr.write_measurements(str(path), mset)
    out = tmp_path / "out"
    argv = [
        "fit",
        str(path),
        "--model",
        "nonparametric",
        "--base-nodes",
        "7",
        "--knots",
        "3",
        "--max-steps",
        "40",
        "--starts",
        "1",
        "--steps",
        "0",
        "--out",
        str(out),
        "--no-progress",
        "--regularisation",
        "2.5",
    ]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "fit.json").read_text())
    assert doc["model"]["kind"] == "nonparametric" and doc["model"]["base_nodes"] == 7
    assert len(doc["model"]["knots_W"]) == 4 and doc["model"]["smoothness"] == 2.5
    status = doc["optimisation"]["status"]
    assert status in ("converged", "nonlinear_max_steps_reached") and status in printed
    assert np.isfinite(doc["optimisation"]["reduced_chi2"])
    # the reported quantities: the amplitude and D_k at the 3 knots of the 2 coarser scales
    names = [n for n in doc["parameters"] if n.startswith("D[")]
    assert len(names) == 6 and "amplitude" in doc["parameters"]
    for name in names + ["amplitude"]:
        row = doc["parameters"][name]
        assert row["source"] == "laplace"
        if row["determined"]:
            assert row["std"] > 0 and row["quantiles_5_50_95"][0] <= row["estimate_map"] <= row["quantiles_5_50_95"][2]
    # amplitude: the integral of the lobe, well determined whatever the tabulation
    amplitude = doc["parameters"]["amplitude"]
    assert amplitude["determined"] and abs(amplitude["estimate_map"] - TRUTH["amplitude"]) < 0.1 * TRUTH["amplitude"]
    assert any("NOT determined" in note for note in doc["identifiability"]["notes"])
    for fig in ("data_vs_fit.png", "statistics.png"):
        assert (out / fig).read_bytes()[:4] == b"\x89PNG"
    assert exr.read_measurements(str(out / "evolved_lobes.exr")).scales.tolist() == list(SCALES)
