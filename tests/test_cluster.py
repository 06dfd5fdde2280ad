"""brdfscale._cluster's checks of the Ray options, the one place both users of Ray (``library.fit_library`` and
``instrument.Measurement.measure``) take them from: bad values are refused with InvalidInputError naming the
option and what it accepts, before any work or output."""

import subprocess
import sys

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


_SIGTERM_SCRIPT = """
import signal
from brdfscale import _cluster

def mine(signum, frame):
    pass

def power(base, exponent):
    return base**exponent

signal.signal(signal.SIGTERM, mine)
with _cluster.ray_session(None, 1, instead="") as ray:
    results = dict(_cluster.as_completed(ray, power, 2, [3, 4]))
    during = signal.getsignal(signal.SIGTERM)
assert results == {0: 8, 1: 16}, results
assert during is not mine, "Ray did not replace the handler: this test no longer tests anything"
assert signal.getsignal(signal.SIGTERM) is mine, signal.getsignal(signal.SIGTERM)
"""


@pytest.mark.slow  # a local Ray instance (~15 s)
def test_a_local_ray_session_gives_the_callers_sigterm_handler_back():
    """``ray.init`` replaces the process's SIGTERM handler and ``ray.shutdown`` leaves it replaced: the session puts
    the caller's back. In a Python process of its own, as a user's script (a Ray driver is never a pytest worker)."""
    pytest.importorskip("ray")
    run = subprocess.run([sys.executable, "-c", _SIGTERM_SCRIPT], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
