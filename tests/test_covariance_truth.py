"""fitting.covariance_truth and fitting.compare_covariance_differences: the true ΔΣ(μ0, μk) of the surface a
measurement set was made from (the lobe widening its images hold), and the pulls of a fit's ΔΣ against it — what
``brdfscale fit`` prints and writes into fit.json (issue 31 item 5: pulls against any truth in the metadata).

The truth is checked against the facet slopes of the set's own field computed here with NumPy (synth.facet_slopes
and np.cov) and against the second moments of the set's own noise-free images, on a field measured throughout and on
the real frt-1 file (holes by its steepest pixels), not against the recorded numbers alone."""

import copy
import json

import numpy as np
import pytest

from brdfscale import fitting, InvalidInputError, stats, synth, topography
from brdfscale._cli._fit import print_covariance_truth
from tests.helpers import image_covariance, TOPOGRAPHIES


@pytest.fixture(scope="module")
def made():
    field = synth.spectral_field(stats.GaussianCorrelation(0.6, (4.0, 12.0)), size=64, seed=2)
    scales = [1.0, 4.0, 16.0]
    return field, scales, synth.gonioreflectometer(field, scales, [0, 0, 1.0], extent=0.6, pixels=9)


def _cov(field, mu):
    """The population covariance of the μ-facet slopes (every pixel of the periodic 64² field lies in a whole
    window at μ = 1, 4, 16: the law of total variance makes the lobe's widening the facets' C(μ0) − C(μ))."""
    return np.cov(np.asarray(synth.facet_slopes(field, mu)).reshape(-1, 2).T, bias=True)


def test_the_truth_is_the_fields_own_facet_covariance_difference(made):
    field, scales, mset = made
    truth = fitting.covariance_truth(mset.metadata, scales)
    assert len(truth) == 2
    for t, mu in zip(truth, scales[1:]):
        np.testing.assert_allclose(t, _cov(field, scales[0]) - _cov(field, mu), rtol=1e-10, atol=1e-15)
    # the field is anisotropic (ℓ_x ≠ ℓ_y): the difference is not a multiple of the identity
    assert abs(truth[0][0][0] - truth[0][1][1]) > 0.1 * abs(truth[0][0][0])


def test_the_truth_follows_the_fitted_scales_and_needs_every_one(made):
    field, scales, mset = made
    (only,) = fitting.covariance_truth(mset.metadata, [4.0, 16.0])
    np.testing.assert_allclose(only, _cov(field, 4.0) - _cov(field, 16.0), rtol=1e-10, atol=1e-15)
    assert fitting.covariance_truth(mset.metadata, [1.0, 8.0]) is None  # 8 was not recorded
    assert fitting.covariance_truth({"scales": scales}, scales) is None  # a file from elsewhere: no record
    assert fitting.covariance_truth(None, scales) is None


@pytest.mark.parametrize("key", ["offset_covariance", "facet_slope_covariance"])
@pytest.mark.parametrize(
    "damage",
    [
        lambda r, k: r.__setitem__(k, r[k][:2]),  # one scale short
        lambda r, k: r[k][0][0].__setitem__(1, float("nan")),
        lambda r, k: r[k][1][0].__setitem__(1, 5.0),  # not symmetric
        lambda r, k: r.__setitem__(k, "x"),
    ],
)
def test_a_damaged_record_is_refused_naming_its_key(made, damage, key):
    _, scales, mset = made
    metadata = copy.deepcopy(mset.metadata)
    if key == "facet_slope_covariance":  # a record without the images' own moments (the instrument's)
        del metadata["truth"]["offset_covariance"]
    damage(metadata["truth"], key)
    with pytest.raises(InvalidInputError, match=rf"metadata truth\.{key} must hold one symmetric"):
        fitting.covariance_truth(metadata, scales)


def test_on_a_field_with_holes_the_truth_is_what_the_images_hold_not_the_facets_difference():
    """frt-1 (a confocal map with 31 % of its pixels unmeasured, by its steepest slopes): a coarser facet is
    measured in fewer places, so the pixel population of the images changes with μ and the facets' C(μ0) − C(μ)
    is not what the images widen by: here the images even narrow (the coarse windows leave out the steep
    pixels). The recorded truth is the images' own widening: checked against the second moments of noise-free
    images that hold all their light (an extent beyond twice the steepest pixel slope, 0.68: an offset from a
    facet's slope, the mean of its pixels', is at most twice as large), within 0.2 % (measured 0.1 %, the
    histogram's binning; at 12× the robust extent, 0.008 % of the light lies outside and the moments'
    difference is 7 % off: the second moment lives in the tails)."""
    field = topography.read(TOPOGRAPHIES / "frt-1.frt")
    scales = [field.spacing[0] * b for b in (2, 24)]
    extent = 2.1 * synth.steepest_slope(field)
    mset = synth.gonioreflectometer(field, scales, [0, 0, 1.0], extent=extent, pixels=1025)
    (truth,) = np.asarray(fitting.covariance_truth(mset.metadata, scales))
    # the node sum of a cloud-in-cell histogram has the samples' mean exactly and their covariance plus the tent's
    # h²/6 per axis, the same at every scale (as is the resolution blur's): differences are the samples' own
    near, far = mset.images
    images = image_covariance(far.values, far.extent) - image_covariance(near.values, near.extent)
    np.testing.assert_allclose(truth, images, rtol=2e-3, atol=2e-3 * abs(truth[0, 0]))
    facets = np.asarray(mset.metadata["truth"]["facet_slope_covariance"])
    assert truth[0, 0] < 0 < facets[0][0, 0] - facets[1][0, 0]


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
    assert lines[0].startswith("ΔΣ(μ0, μk) against the surface the file was made from")
    rows = {line.split()[3]: line for line in lines[2:5]}
    assert rows["xx"].split()[-1] == "-3.50" and rows["xy"].split()[-1] == "2.00" and rows["yy"].split()[-1] == "—"
    assert "1, 4 µm" in rows["xx"]
    assert lines[-1] == "  fit: 1 of 2 entries within 3 std of the truth; largest |pull| 3.5"
    # with the images' own moments (fit.json's moment_covariance_differences): three more columns and a summary
    moments = fitting.compare_covariance_differences(
        [_entry([[0.015, 0.0003], [0.0003, 0.0049]], [[0.001, 0.0001], [0.0001, 0.0002]])],
        [[[0.016, 0.0], [0.0, 0.005]]],
    )
    lines.clear()
    doc = {"covariance_differences": entries, "moment_covariance_differences": moments, "data": {"unit": "µm"}}
    print_covariance_truth(doc, stream=lines.append)
    assert lines[1].split()[-3:] == ["moments", "±", "std", "pull"][1:] and "moments" in lines[1]
    rows = {line.split()[3]: line.split() for line in lines[2:5]}
    assert rows["xx"][-1] == "-1.00" and rows["xy"][-1] == "3.00" and rows["yy"][-1] == "-0.50"
    assert rows["xx"][-4] == "-3.50"  # the fit's pull beside
    assert lines[-2:] == [
        "  fit: 1 of 2 entries within 3 std of the truth; largest |pull| 3.5",
        "  moments: 3 of 3 entries within 3 std of the truth; largest |pull| 3",
    ]
    lines.clear()
    print_covariance_truth({"covariance_differences": [_entry([[0.0] * 2] * 2, [[None] * 2] * 2)]}, lines.append)
    assert lines == []  # no truth: nothing printed


def test_the_truth_table_says_when_a_few_pixel_slopes_carry_the_surfaces_sigma():
    """brdfscale synth --topography records the field's slope outliers (truth.slope_outliers); the command's ΔΣ
    table then ends with their note where they carry most of Σ (the truth is theirs), and with nothing more where
    they do not; a damaged record is the library's own error naming the record."""
    entries = fitting.compare_covariance_differences(
        [_entry([[0.009, 0.001], [0.001, 0.004]], [[0.002, 0.0005], [0.0005, None]])], [[[0.016, 0.0], [0.0, 0.005]]]
    )
    doc = {"covariance_differences": entries, "data": {"unit": "µm"}}
    spiky = topography.SlopeOutliers(10.0, (0.007, 0.01), (0.994, 0.2), (0.01, 0.01), (3e-7, None), (0.65, 0.0), "m")
    calm = topography.SlopeOutliers(10.0, (0.001, 0.001), (0.07, 0.06), (0.01, 0.01), (None, None), (0.0, 0.0), "m")
    tables = {}
    for name, outliers in (("spiky", spiky), ("calm", calm), ("none", None)):
        truth = {} if outliers is None else {"slope_outliers": json.loads(json.dumps(outliers.to_json()))}
        tables[name] = []
        print_covariance_truth(doc, tables[name].append, surface={"truth": truth})
    assert tables["spiky"][-1] == f"  {spiky.note()}" and "99.4 % of their variance" in tables["spiky"][-1]
    assert tables["calm"] == tables["none"] == tables["spiky"][:-1]
    with pytest.raises(InvalidInputError, match="damaged slope-outlier record.*fraction"):
        print_covariance_truth(doc, [].append, surface={"truth": {"slope_outliers": {"threshold": 10}}})
