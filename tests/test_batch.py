"""fitting.fit_many: batched fits equal one-at-a-time fits (ragged data, masks, replicates, mixed
models), divided over 4 virtual CPU devices equal to one device, the bucketing policy."""

import json
import os
import subprocess
import sys
import textwrap
import types

import jax
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from brdfscale import fitting, InvalidInputError, LobeImage, MeasurementSet
from brdfscale.fitting._batch import bucket_points, plan, select_lanes
from tests.helpers import material


def _masked(mset):
    """The same measurement set with a quarter of every second image masked out."""
    images = []
    for k, img in enumerate(mset.images):
        mask = np.ones(img.values.shape[:2], bool)
        if k % 2:
            mask[: img.size // 2, : img.size // 2] = False
        images.append(
            LobeImage(
                mu=img.mu, incident=img.incident, extent=img.extent, values=img.values, sigma=img.sigma, mask=mask
            )
        )
    return MeasurementSet(tuple(images), metadata=mset.metadata)


@pytest.fixture(scope="module")
def ragged():
    msets = [material(i) for i in range(4)] + [_masked(material(4))]
    return [fitting.Dataset.from_measurements(m) for m in msets]


def _assert_same_fit(a, b):
    sd = np.sqrt(np.diag(a.covariance))
    assert a.names == b.names and a.status == b.status
    np.testing.assert_array_less(np.abs(a.theta - b.theta), 1e-3 * sd)
    assert abs(a.chi2 - b.chi2) <= 1e-6 * a.chi2
    for name, s in a.std.items():
        assert (s is None) == (b.std[name] is None)
        if s is not None:
            assert abs(s - b.std[name]) <= 1e-3 * s, name
    assert [u["combination"] for u in a.undetermined] == [u["combination"] for u in b.undetermined]
    assert list(a.ratios) == list(b.ratios)


@pytest.mark.slow  # ~25 s (three fit_many programs); the mixed-models and 4-device tests keep batched = one at a time
def test_batched_fits_equal_one_at_a_time_fits_on_ragged_data(ragged):
    sizes = {d.image_sizes for d in ragged}
    assert len(sizes) > 2 and any(len(d.image_sizes) != len(ragged[0].image_sizes) for d in ragged)
    model = fitting.ParametricModel()
    one = [fitting.fit(model, d, starts=3) for d in ragged]
    many = fitting.fit_many(model, ragged, starts=3)
    for a, b in zip(one, many):
        _assert_same_fit(a, b)
    # every rung apart (no merging): the same results from three programs instead of one
    apart = fitting.fit_many(model, ragged, starts=3, compile_rows=0)
    assert len(fitting.explain_plan(model, ragged, starts=3, compile_rows=0).buckets) > 1
    for a, b in zip(one, apart):
        _assert_same_fit(a, b)


@pytest.mark.slow  # ~20 s on 2 cores: keeps the default suite under its 6 minutes
def test_mixed_models_go_to_separate_buckets_and_keep_their_order(ragged):
    models = [fitting.ParametricModel(), fitting.ParametricModel(fixed={"mu_c": 1.0})] * 2
    data = ragged[:4]
    layout = fitting.explain_plan(models, data, starts=2)
    assert len(layout.buckets) == 2 and sorted(m for b in layout.buckets for m in b.materials) == [0, 1, 2, 3]
    assert "2 bucket(s)" in layout.explain()
    many = fitting.fit_many(models, data, starts=2)
    for model, d, b in zip(models, data, many):
        _assert_same_fit(fitting.fit(model, d, starts=2), b)


def test_fit_many_refuses_what_it_cannot_pair(ragged):
    model = fitting.ParametricModel()
    with pytest.raises(InvalidInputError, match="pair up"):
        fitting.fit_many([model, model], ragged[:3])
    with pytest.raises(InvalidInputError, match="sequence of datasets"):
        fitting.fit_many(model, ragged[0])
    with pytest.raises(InvalidInputError, match="batch"):
        fitting.fit_many(model, ragged, batch=0)
    with pytest.raises(InvalidInputError, match="devices=9"):
        fitting.fit_many(model, ragged, devices=9)
    with pytest.raises(InvalidInputError, match="material 1"):
        fitting.fit_many(model, [ragged[0], "data"])
    with pytest.raises(InvalidInputError, match="errors"):
        fitting.fit_many(model, ragged, errors="ignore")


@pytest.mark.slow  # ~17 s of compilation; the default suite keeps under 6 minutes
def test_lanes_change_how_solves_run_not_the_fits(ragged):
    """lanes=1 (the CPU default: a lax.map, each solve its own iterations), groups of 4 (a
    lax.map of vmapped groups) and all (one vmap in lock-step, the accelerators' default) give
    the same fits to the solver's tolerance."""
    model = fitting.ParametricModel()
    assert select_lanes(jax.devices()) == 1  # CPU
    assert select_lanes([types.SimpleNamespace(platform="gpu")]) == sys.maxsize
    assert select_lanes(jax.devices(), 4) == 4
    default = fitting.fit_many(model, ragged, starts=3)
    assert select_lanes(jax.devices(), "all") == sys.maxsize
    for lanes in (4, "all"):
        layout = fitting.explain_plan(model, ragged, starts=3, lanes=lanes)
        (bucket,) = layout.buckets
        # 5 materials → a run of 6 (the ladder) × 3 starts = 18 solves, rounded up to whole groups
        assert bucket.solves == (20 if lanes == 4 else 18) and bucket.lanes == (4 if lanes == 4 else 18)
        assert ("4 at a time" if lanes == 4 else "all in lock-step") in layout.explain()
        for a, b in zip(default, fitting.fit_many(model, ragged, starts=3, lanes=lanes)):
            _assert_same_fit(a, b)
    assert "one solve at a time" in fitting.explain_plan(model, ragged, starts=3).explain()
    for bad in (0, "some", 2.5):
        with pytest.raises(InvalidInputError, match="lanes must be"):
            fitting.fit_many(model, ragged, lanes=bad)


@given(st.integers(1, 100_000))
@settings(max_examples=300, deadline=None)
def test_bucket_points_bounds_the_padding(n):
    size = bucket_points(n)
    assert size >= n and size >= 8
    assert size <= max(8, 1.5 * n)
    assert size % 8 == 0 or size in (12,)


def test_plan_merges_rungs_only_when_padding_is_cheaper_than_compiling(ragged):
    problems = [fitting.Problem(fitting.ParametricModel(), d) for d in ragged]
    apart, merged = plan(problems, 4, 64, 1, compile_rows=0), plan(problems, 4, 64, 1, compile_rows=10**9)
    rungs = {bucket_points(p.points.mean.shape[1]) for p in problems}
    assert len(apart.buckets) == len(rungs) and len(merged.buckets) == 1
    assert merged.buckets[0].points == max(rungs) and apart.padding <= merged.padding
    # the padding fraction is what the rows say
    used = sum(p.points.mean.shape[0] * p.points.mean.shape[1] * 4 for p in problems)
    assert apart.rows_used == used and apart.padding == pytest.approx(1 - used / apart.rows_padded)
    # batches: at most `batch` materials a program run, padded on the 1, 2, 3, 4, 6, 8 … ladder
    small = plan(problems, 1, 2, 1, compile_rows=10**9)
    assert [len(b.materials) for b in small.buckets] == [2, 2, 1]


_SHARDED = textwrap.dedent("""
    import json, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from brdfscale import fitting
    import brdfscale.fitting._batch as batch
    from tests.helpers import material
    assert len(jax.devices()) == 4, jax.devices()
    data = [fitting.Dataset.from_measurements(material(i)) for i in (0, 1, 5)]
    assert len({d.image_sizes for d in data}) == 3  # ragged: 32² × 1, 28² × 2, 24² × 2 images
    model = fitting.ParametricModel()
    # record the device each run of the batched program computes on (the program is not changed)
    placed, solve = [], batch._solve_batch
    def recording(*args):
        out = solve(*args)
        placed.append([d.id for d in out[0].devices()])
        return out
    batch._solve_batch = recording
    one = fitting.fit_many(model, data, devices=1, starts=2)
    four = fitting.fit_many(model, data, devices=4, starts=2)
    json.dump({"theta": [[r.theta.tolist() for r in res] for res in (one, four)],
               "chi2": [[r.chi2 for r in res] for res in (one, four)],
               "devices_of_output": placed}, sys.stdout)
""")


@pytest.mark.slow  # ~20 s on 2 cores: keeps the default suite under its 6 minutes
def test_batched_fits_divided_over_4_devices_equal_one_device_bit_for_bit():
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"}
    run = subprocess.run(
        [sys.executable, "-c", _SHARDED],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    )
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    one, four = (np.asarray(t) for t in got["theta"])
    # devices=1: one run on device 0; devices=4: one run on each device, each on its own slice
    assert got["devices_of_output"][0] == [0]
    assert sorted(got["devices_of_output"][1:]) == [[0], [1], [2], [3]]
    # the same program on a quarter of the batch: bit for bit on CPU — so the 4-device fits equal
    # one-at-a-time fits exactly as the 1-device ones do (test_batched_fits_equal_one_at_a_time_fits_on_ragged_data)
    np.testing.assert_array_equal(one, four)
    np.testing.assert_array_equal(got["chi2"][0], got["chi2"][1])
