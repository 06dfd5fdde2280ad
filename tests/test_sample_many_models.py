"""fitting.sample_many with the default (anisotropic) model: each material's chain is the one
fitting.sample draws alone to rounding, not necessarily bit for bit (fitting._sample_many, "What is
equal": stacked, XLA rewrites the Gaussian density's division by each material's determinant as a
multiplication by its reciprocal). tests/test_sample_many.py shows the bit-for-bit equality of a
model whose stacked program XLA compiles as the single one; tests/test_library.py the library's."""

import numpy as np
import pytest

from tests.helpers import material


@pytest.mark.slow  # ~35 s of CPU (the anisotropic model's programs compile for the stack and alone)
def test_anisotropic_materials_sampled_together_agree_with_sample_to_rounding():
    import jax

    from brdfscale import fitting

    jax.config.update("jax_enable_x64", True)
    data = [fitting.Dataset.from_measurements(material(i)) for i in (1, 3)]
    models = [fitting.AnisotropicModel(len(d.scales)) for d in data]
    problems = [fitting.Problem(m, d) for m, d in zip(models, data)]
    fits = fitting.fit_many(models, data, starts=1, solver="lm_normal")
    options = dict(sampler=fitting.NUTS(warmup=20), chains=2, steps=20, seed=3)
    many = fitting.sample_many(problems, fits, **options)
    for problem, fit, drawn in zip(problems, fits, many):
        alone = fitting.sample(problem, fit, progress=False, **options)
        assert drawn.chain.shape == alone.chain.shape == (40, 2, len(models[0].names)) and drawn.burn == alone.burn
        np.testing.assert_allclose(drawn.chain, alone.chain, rtol=0, atol=1e-10)
        np.testing.assert_allclose(drawn.log_prob, alone.log_prob, rtol=1e-12)
        np.testing.assert_array_equal(drawn.stats["integration_steps"], alone.stats["integration_steps"])
