"""fitting.covariance_truth and fitting.compare_covariance_differences: the true ΔΣ(μ0, μk) of the surface a
measurement set was made from (its recorded facet statistics), and the pulls of a fit's ΔΣ against it — what
``brdfscale fit`` prints and writes into fit.json (issue 31 item 5: pulls against any truth in the metadata).

The truth is checked against the facet slopes of the set's own field computed here with NumPy (synth.facet_slopes
and np.cov), not against the recorded numbers alone."""

import copy

import numpy as np
import pytest

from brdfscale import fitting, InvalidInputError, stats, synth
from brdfscale._cli._fit import print_covariance_truth


@pytest.fixture(scope="module")
def made():
    field = synth.spectral_field(stats.GaussianCorrelation(0.6, (4.0, 12.0)), size=64, seed=2)
    scales = [1.0, 4.0, 16.0]
    return field, scales, synth.gonioreflectometer(field, scales, [0, 0, 1.0], extent=0.6, pixels=9)


def _cov(field, mu):
    return np.cov(np.asarray(synth.facet_slopes(field, mu)).reshape(-1, 2).T)


def test_the_truth_is_the_fields_own_facet_covariance_difference(made):
    field, scales, mset = made
    truth = fitting.covariance_truth(mset.metadata, scales)
    assert len(truth) == 2
    for t, mu in zip(truth, scales[1:]):
        np.testing.assert_allclose(t, _cov(field, scales[0]) - _cov(field, mu), rtol=1e-12, atol=1e-15)
    # the field is anisotropic (ℓ_x ≠ ℓ_y): the difference is not a multiple of the identity
    assert abs(truth[0][0][0] - truth[0][1][1]) > 0.1 * abs(truth[0][0][0])


def test_the_truth_follows_the_fitted_scales_and_needs_every_one(made):
    field, scales, mset = made
    (only,) = fitting.covariance_truth(mset.metadata, [4.0, 16.0])
    np.testing.assert_allclose(only, _cov(field, 4.0) - _cov(field, 16.0), rtol=1e-12, atol=1e-15)
    assert fitting.covariance_truth(mset.metadata, [1.0, 8.0]) is None  # 8 was not recorded
    assert fitting.covariance_truth({"scales": scales}, scales) is None  # a file from elsewhere: no record
    assert fitting.covariance_truth(None, scales) is None


@pytest.mark.parametrize(
    "damage",
    [
        lambda r: r.__setitem__("facet_slope_covariance", r["facet_slope_covariance"][:2]),  # one scale short
        lambda r: r["facet_slope_covariance"][0][0].__setitem__(1, float("nan")),
        lambda r: r["facet_slope_covariance"][1][0].__setitem__(1, 5.0),  # not symmetric
        lambda r: r.__setitem__("facet_slope_covariance", "x"),
    ],
)
def test_a_damaged_record_is_refused_naming_its_key(made, damage):
    _, scales, mset = made
    metadata = copy.deepcopy(mset.metadata)
    damage(metadata["truth"])
    with pytest.raises(InvalidInputError, match=r"metadata truth\.facet_slope_covariance must hold one symmetric"):
        fitting.covariance_truth(metadata, scales)


def _entry(value, std, fixed=None):
    return {"mu0": 1.0, "mu": 4.0, "value": value, "std": std, **({"fixed": fixed} if fixed else {})}


def test_pulls_by_hand_and_none_where_nothing_was_measured():
    entries = [
        _entry([[0.010, 0.001], [0.001, 0.004]], [[0.002, 0.0005], [0.0005, None]]),
        _entry([[0.020, 0.0], [0.0, 0.020]], [[0.004, None], [None, 0.004]], [[False, True], [True, False]]),
    ]
    truth = [[[0.016, 0.0], [0.0, 0.005]], [[0.019, 0.002], [0.002, 0.030]]]
    out = fitting.compare_covariance_differences(entries, truth)
    assert out[0]["pull"] == [[pytest.approx(-3.0), pytest.approx(2.0)], [pytest.approx(2.0), None]]
    assert out[1]["pull"] == [[pytest.approx(0.25), None], [None, pytest.approx(-2.5)]]  # ΔΣ_xy fixed: no pull
    assert out[0]["truth"] == truth[0] and out[0]["value"] == entries[0]["value"]
    assert fitting.compare_covariance_differences(entries, None) is entries
    assert fitting.compare_covariance_differences(entries, truth[:1]) is entries  # not one per entry


def test_the_command_prints_truth_estimate_and_pull_per_entry():
    entries = fitting.compare_covariance_differences(
        [_entry([[0.009, 0.001], [0.001, 0.004]], [[0.002, 0.0005], [0.0005, None]])], [[[0.016, 0.0], [0.0, 0.005]]]
    )
    lines = []
    print_covariance_truth({"covariance_differences": entries, "data": {"unit": "µm"}}, stream=lines.append)
    assert lines[0].startswith("ΔΣ(μ0, μk) against the facet statistics")
    rows = {line.split()[3]: line for line in lines[2:5]}
    assert rows["xx"].split()[-1] == "-3.50" and rows["xy"].split()[-1] == "2.00" and rows["yy"].split()[-1] == "—"
    assert "1, 4 µm" in rows["xx"]
    assert lines[-1] == "  1 of 2 entries within 3 std of the truth; largest |pull| 3.5"
    lines.clear()
    print_covariance_truth({"covariance_differences": [_entry([[0.0] * 2] * 2, [[None] * 2] * 2)]}, lines.append)
    assert lines == []  # no truth: nothing printed
