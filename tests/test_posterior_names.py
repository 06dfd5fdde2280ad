"""Every model's coordinate and quantity names survive ``posterior.nc`` (fitting._report writes
``SampleResult.to_arviz()`` with h5netcdf, which refuses "/" in a variable name): written as the
report writes it and read back by ArviZ's own reader, one variable per name."""

import jax
import numpy as np
import pytest

from brdfscale import fitting, library
from brdfscale._choices import MODELS


jax.config.update("jax_enable_x64", True)

from tests.helpers import anisotropic_dataset  # noqa: E402


@pytest.fixture(scope="module")
def data():
    return anisotropic_dataset(0)


@pytest.mark.parametrize("name", MODELS.names)
def test_every_models_names_are_written_to_posterior_nc_and_read_back(name, data, tmp_path):
    az = pytest.importorskip("arviz")
    pytest.importorskip("h5netcdf")
    model, _ = library.make_model(data, model=name, base_nodes=5, knots=2)
    assert type(model) is library.model_class(name)
    theta0 = np.asarray(model.initial(data))
    steps, trajectories, d = 6, 2, theta0.size
    rng = np.random.default_rng(0)
    chain = theta0 + 1e-3 * rng.standard_normal((steps, trajectories, d))
    quantities = fitting._derived.quantities_at(model, chain)
    samples = fitting.SampleResult(
        names=model.names,
        chain=chain,
        log_prob=rng.standard_normal((steps, trajectories)),
        burn=2,
        tau=np.ones(d),
        ess=np.ones(d),
        tau_reliable=False,
        acceptance=0.5,
        sampler="nuts",
        chains=trajectories,
        quantities=quantities,
    )
    path = fitting._report._write_posterior(str(tmp_path), samples, overwrite=False)
    back = az.from_netcdf(path)
    expected = list(model.names) + [q for q in quantities if q not in model.names]
    assert list(back.posterior.data_vars) == expected
    for i, n in enumerate(model.names):
        np.testing.assert_array_equal(back.posterior[n].values, np.swapaxes(chain[2:, :, i], 0, 1))
