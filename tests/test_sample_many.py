"""fitting.sample_many: NUTS and HMC on many posteriors in one vmapped program per bucket equal
fitting.sample one material at a time, bit for bit (ragged data padded, window adaptation,
materials of different sampled dimension in separate buckets), and what it refuses.

The posteriors are those of the linear model of tests/test_samplers.py (cheap to compile and
evaluate) on small datasets of different sizes: 7×7 and 8×8 pixels per scale, or one of each
(49 or 64 distinct points per scale, all padded to the rung of 64). ``fitting.sample`` evaluates
its log-density on the same padded rows (fitting._posterior.padded_rows), so the draws,
statistics, warm-up and diagnostics are equal exactly, not only to rounding: on the unpadded
rows the padded material's chain differed at rounding level (a longer χ² sum rounds
differently), enough to move its rank-normalised R̂ (folded draws tie at the median in one run
and not in the other) and with it the status text.
"""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from brdfscale import fitting, InvalidInputError
from brdfscale.fitting import _sample_many
from tests.helpers import Linear, linear_measurements


SIGMA = 0.1
SIZES = [(7, 7), (8, 8), (8, 7)]  # pixels per side at the two scales: 49, 64, 64 distinct points
NUTS = dict(sampler=fitting.NUTS(warmup=30), chains=2, steps=30, chunk=25, seed=1)


@pytest.fixture(scope="module")
def ragged():
    model = Linear()
    problems = [
        fitting.Problem(model, fitting.Dataset.from_measurements(linear_measurements(i, s, SIGMA)))
        for i, s in enumerate(SIZES)
    ]
    assert [p.points.mean.shape[1] for p in problems] == [49, 64, 64]
    return problems, [fitting.fit(model, p.data, starts=1) for p in problems]


def _assert_same(one, many):
    """``many`` is ``one``: chain, densities, statistics and warm-up bit for bit, the same diagnostics."""
    assert isinstance(many, fitting.SampleResult)
    assert (many.names, many.burn, many.sampler, many.chains, many.status) == (
        one.names,
        one.burn,
        one.sampler,
        one.chains,
        one.status,
    )
    np.testing.assert_array_equal(many.chain, one.chain)
    np.testing.assert_array_equal(many.log_prob, one.log_prob)
    assert many.stats.keys() == one.stats.keys()
    for k in one.stats:
        np.testing.assert_array_equal(many.stats[k], one.stats[k], err_msg=k)
    a, b = one.diagnostics(), many.diagnostics()
    assert set(b.pop("timing_s")) == set(a.pop("timing_s")) == {"warmup_s", "sampling_s"}
    np.testing.assert_equal(b, a)  # summary, warm-up record, held combinations (NaN equal to NaN)


def _count_traces(monkeypatch):
    """How often sample_many's vmapped program is traced (compiled): once per trace it calls ``_advance``."""
    calls = []
    original = _sample_many._advance

    def counted(*args):
        calls.append(1)
        return original(*args)

    monkeypatch.setattr(_sample_many, "_advance", counted)
    return calls


@pytest.mark.slow  # ~11 s; sample_many = sample: test_hmc_with_window_adaptation_equals_sample (slow too); window
# adaptation in the default suite: tests/test_samplers.py's nuts-windows resume
def test_nuts_on_ragged_materials_equals_sample_one_at_a_time(ragged, monkeypatch):
    problems, fits = ragged
    traces = _count_traces(monkeypatch)
    many = fitting.sample_many(problems, fits, **NUTS)
    # one bucket: one program for the warm-up's and the draws' chunks (25, 5, 25, 5 steps) of all
    # materials (the file's first NUTS bucket of three: nothing compiled before)
    assert len(traces) == 1
    for problem, fit, result in zip(problems, fits, many):
        _assert_same(fitting.sample(problem, fit, progress=False, **NUTS), result)
    # timing: the bucket's seconds shared equally by its materials
    assert all(r.timing == many[0].timing for r in many) and many[0].timing["warmup_s"] > 0


@pytest.mark.slow  # 18 s on 2 cores: the default suite measured 402 s at ff4fa2c (budget 360)
def test_hmc_with_window_adaptation_equals_sample(ragged):
    problems, fits = ragged
    options = dict(sampler=fitting.HMC(warmup=20, adapt_mass_matrix=True), chains=2, steps=20, chunk=25, seed=2)
    many = fitting.sample_many(problems[:2], fits[:2], **options)
    for problem, fit, result in zip(problems, fits, many):
        one = fitting.sample(problem, fit, progress=False, **options)
        assert one.warmup["kind"].startswith("BlackJAX window_adaptation")
        _assert_same(one, result)


@pytest.mark.slow  # ~20 s on 2 cores: keeps the default suite under its 6 minutes
def test_materials_of_another_sampled_dimension_go_to_their_own_bucket(ragged, monkeypatch):
    """A fit with a stricter undetermined_std has an undetermined combination: its chain samples a
    2-dimensional plane instead of 3, so it cannot share the others' program (same model, same points)."""
    problems, fits = ragged
    strict = fitting.fit(problems[1].model, problems[1].data, starts=1, undetermined_std=0.02)
    assert len(strict.undetermined) == 1
    problems, fits = problems + [problems[1]], fits + [strict]
    stacks = []
    stack = _sample_many.stack_trees
    monkeypatch.setattr(_sample_many, "stack_trees", lambda trees: stacks.append(trees) or stack(trees))
    traces = _count_traces(monkeypatch)
    many = fitting.sample_many(problems, fits, **NUTS)
    # two buckets: m = 3 (three materials, test 1's program) and m = 2 (one), a program each
    assert [[t.dimension for t in trees] for trees in stacks] == [[3, 3, 3], [2]]
    assert len(traces) <= 2
    for problem, fit, result in zip(problems, fits, many):
        _assert_same(fitting.sample(problem, fit, progress=False, **NUTS), result)
    assert many[3].held[0]["combination"] == strict.undetermined[0]["combination"]


def test_what_sample_many_refuses(ragged):
    problems, fits = ragged
    for sampler in ("emcee", fitting.Emcee(walkers=8)):
        with pytest.raises(InvalidInputError, match="do not vectorise across materials"):
            fitting.sample_many(problems, fits, sampler=sampler)
    for sampler in ("auto", fitting.Auto(), "imh"):  # fitting.sample's default is not sample_many's (NUTS)
        with pytest.raises(InvalidInputError, match="NUTS or HMC only"):
            fitting.sample_many(problems, fits, sampler=sampler)
    for args, match in [
        ((problems, fits[:2]), "pair up"),
        ((problems[0], fits[0]), "sequence of problems"),
        ((problems, [fits[0], fits[1], "fit"]), "material 2"),
        (([], []), "at least one"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            fitting.sample_many(*args)
    other = fitting.Problem(Linear(duplicate=True), problems[0].data)
    with pytest.raises(InvalidInputError, match="material 1: fit is the result for 3 coordinates"):
        fitting.sample_many([problems[0], other], fits[:2], errors="return")  # a wrong pairing is always refused
    for kw, match in [
        (dict(errors="ignore"), "errors"),
        (dict(batch=0), "batch"),
        (dict(steps=1), "steps"),
        (dict(devices=9), "devices=9"),
        (dict(sampler="metropolis"), "sampler must be one of"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            fitting.sample_many(problems, fits, **kw)


@pytest.mark.slow  # 11 s on 2 cores (NUTS compiled twice): the default suite measured 372 s at fc7a33e (budget 360)
def test_what_sample_many_cannot_sample_is_raised_or_returned_in_its_slot(ragged):
    """A material the data determine nowhere: raised, or returned in its slot while the others are sampled."""
    problems, fits = ragged
    nothing = fitting.fit(problems[1].model, problems[1].data, starts=1, undetermined_std=1e-9)
    assert len(nothing.undetermined) == 3
    with pytest.raises(InvalidInputError, match="material 3: .*nothing to sample"):
        fitting.sample_many(problems + [problems[1]], fits + [nothing], **NUTS)
    failed = InvalidInputError("every start ended with a non-finite χ²")  # fit_many(…, errors="return")'s entry
    out = fitting.sample_many(problems + [problems[1], problems[0]], fits + [nothing, failed], errors="return", **NUTS)
    assert [type(r) for r in out[:3]] == [fitting.SampleResult] * 3
    assert isinstance(out[3], InvalidInputError) and "material 3" in str(out[3])
    assert isinstance(out[4], InvalidInputError) and "material 4: its fit failed: every start" in str(out[4])
    _assert_same(fitting.sample(problems[0], fits[0], progress=False, **NUTS), out[0])


_SHARDED = textwrap.dedent("""
    import json, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from brdfscale import fitting
    from brdfscale.fitting import _sample_many
    from tests.helpers import Linear, linear_measurements
    from tests.test_sample_many import NUTS, SIGMA, SIZES
    assert len(jax.devices()) == 2, jax.devices()
    problems = [fitting.Problem(Linear(), fitting.Dataset.from_measurements(linear_measurements(i, s, SIGMA)))
                for i, s in enumerate(SIZES)]
    fits = [fitting.fit(Linear(), p.data, starts=1) for p in problems]
    placed, advance = [], _sample_many._advance_many
    def recording(*args):
        out = advance(*args)
        placed.append(len(out[1][0].sharding.device_set))
        return out
    _sample_many._advance_many = recording
    many = fitting.sample_many(problems, fits, devices=2, **NUTS)
    one = [fitting.sample(p, f, progress=False, **NUTS) for p, f in zip(problems, fits)]
    json.dump({"difference": [float(np.max(np.abs(a.chain - b.chain))) for a, b in zip(one, many)],
               "same": [(a.names, a.burn) == (b.names, b.burn) for a, b in zip(one, many)],
               "devices_of_output": sorted(set(placed))}, sys.stdout)
""")


@pytest.mark.slow
def test_sharded_over_two_devices_equals_sample_to_rounding():
    """Two virtual CPU devices, three materials (padded to four, two a device): the chains
    equal ``sample``'s to rounding — the per-device program is compiled apart and the
    log-density's gradient differs in the last bits (at rounding level over 60 steps; 1e-9
    leaves room for other platforms' rounding, not for a parted chain, which differs by O(σ))."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
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
    assert got["devices_of_output"] == [2] and all(got["same"])
    assert max(got["difference"]) < 1e-9, got["difference"]
