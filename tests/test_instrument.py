"""brdfscale.instrument: the ray-traced virtual gonioreflectometer (issue 32 items 1–3)."""

import numpy as np
import pytest

import brdfscale
from brdfscale import instrument, lobes, stats, synth


pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def smooth():
    """A smooth periodic Gaussian surface, 64², correlation length 8 px (rms slope ≈ 0.05)."""
    return synth.spectral_field(stats.GaussianCorrelation(rms_height=0.3, correlation_length=8.0), size=64, seed=1)


def test_measure_returns_a_measurement_set_in_the_synth_layout(smooth):
    m = instrument.measure(smooth, [4, 16], [0, 0, 1], extent=0.15, pixels=33, rays=4000, seed=0, progress=False)
    g = synth.gonioreflectometer(smooth, [4, 16], [0, 0, 1], extent=0.15, pixels=33)
    assert isinstance(m, brdfscale.MeasurementSet) and len(m.images) == 2
    assert [p.mu for p in m.images] == [p.mu for p in g.images]
    assert all(p.sigma is not None and np.all(p.sigma > 0) for p in m.images)
    assert set(g.metadata) - {"weighting"} <= set(m.metadata)
    record = m.metadata["instrument"]
    assert record["rays"] == 4000 and record["bounces"] == 1 and record["variant"]


def test_same_seed_is_bit_identical(smooth):
    a = instrument.measure(smooth, 8, [0.1, 0, np.sqrt(0.99)], extent=0.15, pixels=17, rays=2000, seed=3, progress=False)
    b = instrument.measure(smooth, 8, [0.1, 0, np.sqrt(0.99)], extent=0.15, pixels=17, rays=2000, seed=3, progress=False)
    assert np.array_equal(a.images[0].values, b.images[0].values)
    assert np.array_equal(a.images[0].sigma, b.images[0].sigma)
