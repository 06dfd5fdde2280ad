"""The density check (brdfscale.stats.require_density) is the one place that refuses a
plus-distribution where a probability density of facet slopes is needed: every entry point
says the same thing, naming its own argument and what to give instead."""

import numpy as np
import pytest

import brdfscale as bs
from brdfscale import InvalidInputError, lobes, plus, so3, stats, synth


H0 = plus.PlusDistribution(0, 0.1)
COMMON = (
    r"must be (a probability density|probability densities) of facet slopes \(mass 1\); got PlusDistribution, "
    r"a generalised function of mass 0 with no pointwise density \(a plus-distribution h_n\)"
)

CALLS = {
    "shape": lambda h: lobes.Lobe(h),
    "components": lambda h: stats.Mixture([0.5, 0.5], [stats.Beckmann(0.1), h]),
    "smooth": lambda h: plus.NearlySpecular(0.5, [0.1], 0.1, smooth=h, smooth_weight=0.5),
    "s_from": lambda h: bs.evolve(lobes.GGX(0.08), h, stats.Delta()),
    "micro": lambda h: synth.HeightField(np.zeros((8, 8)), 1.0, micro=h),
    "tilt": lambda h: so3.TiltTwist(h),
}
# entry points whose argument is annotated as a density: with jaxtyping's runtime checks on, the annotation's
# check refuses a plus-distribution or a string first (wrong_types), before the library's own message
ANNOTATED = {"shape", "s_from", "tilt"}
NAMES = [pytest.param(name, marks=pytest.mark.wrong_types) if name in ANNOTATED else name for name in CALLS]


@pytest.mark.parametrize("name", NAMES)
def test_every_entry_point_refuses_a_plus_distribution_in_the_same_words(name):
    with pytest.raises(InvalidInputError, match=f"^{name} {COMMON}. [A-Z]"):
        CALLS[name](H0)


@pytest.mark.parametrize("name", NAMES)
def test_every_entry_point_refuses_what_is_no_density(name):
    with pytest.raises(InvalidInputError, match=f"^{name} must be (a )?brdfscale.stats densit"):
        CALLS[name]("wide")


def test_a_density_is_returned_as_it_is():
    density = stats.Beckmann(0.1)
    assert stats.require_density(density, "s") is density
    assert stats.require_density((density, stats.Delta()), "components", each=True) == (density, stats.Delta())
