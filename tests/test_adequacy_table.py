"""The per-scale adequacy table and the truth table of ``brdfscale fit`` never print nan: a scale
where the model's prediction is not finite at a valid pixel has no χ² (fitting.assess: None, the
scale inadequate, the reason naming it), whatever the model predicts at masked pixels is left out,
and an undetermined quantity's std and interval are words (brdfscale._cli._fit.print_outcome,
print_truth). The slow end-to-end case is tests/test_scale_invariance.py's fit command on a law held
at alpha_max = 9."""

import dataclasses
import re

import jax.numpy as jnp
import numpy as np
import pytest

from brdfscale import fitting, MeasurementSet
from brdfscale._cli._fit import print_outcome, print_truth
from tests.helpers import Linear, linear_measurements


class _Holey(Linear):
    """The linear model with a hole: NaN at the corner u = (0.1, 0.1) of scale 1 (μ = 2) and +∞ at
    the corner u = (−0.1, −0.1) of scale 0, which the data mask."""

    def predict_points(self, theta, scales, points):
        f = super().predict_points(theta, scales, points)
        k = jnp.arange(points.shape[0])[:, None]
        x, y = points[..., 0], points[..., 1]
        f = jnp.where((k == 1) & (x > 0.099) & (y > 0.099), jnp.nan, f)
        return jnp.where((k == 0) & (x < -0.099) & (y < -0.099), jnp.inf, f)


@pytest.fixture(scope="module")
def holey():
    mset = linear_measurements(size=6)
    first = mset.images[0]
    mask = np.ones(first.values.shape, bool)
    mask[0, 0] = False  # u = (−0.1, −0.1): the model's +∞ there is no concern of the fit
    images = (dataclasses.replace(first, mask=mask), *mset.images[1:])
    data = fitting.Dataset.from_measurements(MeasurementSet(images))
    fit = fitting.fit(Linear(), data, starts=1)  # the same θ coordinates: a fit of the hole-free model
    return fitting.Problem(_Holey(), data), fit


def _table(doc) -> list[str]:
    lines = []
    print_outcome(doc, stream=lines.append)
    return lines


def test_a_scale_whose_prediction_is_not_finite_has_no_chi2_and_is_inadequate(holey):
    problem, fit = holey
    outcome = fitting.assess(problem, fit)
    masked, holed = outcome.scales
    # the masked +∞ is left out: scale 0's figures are the hole-free model's own
    clean = fitting.assess(fitting.Problem(Linear(), problem.data), fit).scales
    assert masked == clean[0] and np.isfinite(masked["reduced_chi2"]) and masked["chi2_p"] > 1e-3
    figures = ("chi2", "reduced_chi2", "chi2_p", "lag1_rows", "lag1_cols", "lag1_p", "moments_z", "moments_p")
    assert [holed[key] for key in figures] == [None] * 8
    assert holed["dof"] == clean[1]["dof"] and holed["mu"] == 2.0 and holed["width_px"] == clean[1]["width_px"]
    assert outcome.status == "inadequate"
    assert outcome.reason.startswith("model inadequate at μ = 2 px: its prediction is not finite at 1 of the 36 valid")
    lines = _table({"outcome": outcome.to_json(), "data": {"unit": None}})
    text = "\n".join(lines)
    assert re.search(r"\bnan\b", text, re.IGNORECASE) is None, text
    assert re.fullmatch(r" +2( +undefined){7} +[0-9.]+ +undefined", lines[3]), text
    mu0 = r" +1 +[0-9.]+ +[0-9.]+ +[0-9.]+ +[0-9.]+ +[0-9.]+ +— +— +[0-9.]+ +(—|[0-9.]+)"  # no ΔΣ at μ0
    assert re.fullmatch(mu0, lines[2]), text
    assert lines[-1] == f"  outcome: inadequate — {outcome.reason}"
    # a report written before the away column: "—" there, the rest as before
    old = outcome.to_json()
    for row in old["scales"]:
        del row["away_share"]
    assert _table({"outcome": old, "data": {"unit": None}})[2].endswith(" —")


def test_the_truth_table_prints_an_undetermined_quantity_in_words():
    row = {"estimate_map": 0.05, "determined": False, "std": None, "quantiles_5_50_95": None, "median": None}
    doc = {
        "parameters": {
            "exponent": {**row, "truth": 0.8},
            "mu_c": {"estimate_map": 1.5, "std": 0.25, "quantiles_5_50_95": [1.1, 1.5, 1.9], "median": 1.5, "truth": 1},
            "extra": {"estimate_map": 2.0, "std": 0.5, "quantiles_5_50_95": [1.2, 2.0, 2.8], "median": None},
        }
    }
    lines = []
    print_truth(doc, stream=lines.append)
    assert re.search(r"\bnan\b", "\n".join(lines), re.IGNORECASE) is None, lines
    assert lines[1].split() == ["exponent", "0.8", "0.05", "undetermined", "—", "—", "—"]
    assert lines[2].split() == ["mu_c", "1", "1.5", "0.25", "1.1", "1.9", "2.00"]  # |1.5 − 1|/0.25
    assert lines[3].split() == ["extra", "unknown", "2", "0.5", "1.2", "2.8", "—"]
