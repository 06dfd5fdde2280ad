"""brdfscale._cluster's checks of the Ray options, the one place both users of Ray (``library.fit_library`` and
``instrument.Measurement.measure``) take them from: bad values are refused with InvalidInputError naming the
option and what it accepts, before any work or output."""

import numpy as np
import pytest

from brdfscale import _cluster, instrument, InvalidInputError, library, synth


def test_ray_options_are_checked_and_returned():
    assert _cluster.check_options(None, 1, 2) == (None, 1.0, 2)
    assert _cluster.check_options(np.int64(3), 0.5, 0) == (3, 0.5, 0)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ((0, 1, 2), r"workers.*≥ 1"),
        ((2.5, 1, 2), r"workers"),
        ((None, 0, 2), r"cpus_per_task.*> 0"),
        ((None, float("nan"), 2), r"cpus_per_task"),
        ((None, 1, -1), r"retries.*≥ 0"),
        ((None, 1, True), r"retries"),
    ],
)
def test_bad_ray_options_are_refused_by_name(options, message):
    with pytest.raises(InvalidInputError, match=message):
        _cluster.check_options(*options)


def test_fit_library_refuses_bad_cpus_per_task_before_writing(tmp_path):
    out = tmp_path / "library"
    with pytest.raises(InvalidInputError, match=r"cpus_per_task"):
        library.fit_library([str(tmp_path)], str(out), cpus_per_task=0, progress=False)
    assert not out.exists()


def test_instrument_refuses_bad_ray_options_before_tracing():
    field = synth.HeightField(np.zeros((8, 8)), 1.0)
    plan = instrument.Measurement(field, [1, 2], [0.0, 0.0, 1.0], extent=0.1, pixels=5, rays=64, batches=2)
    with pytest.raises(InvalidInputError, match=r"cpus_per_task"):
        plan.measure(progress=False, cpus_per_task=-1)
    with pytest.raises(InvalidInputError, match=r"retries"):
        plan.measure(progress=False, retries=-1)
