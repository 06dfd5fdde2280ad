"""Measurement sets generated from a fitting model plus Gaussian noise (tests, demo, studies).

This is the forward model run on a known θ, sampled on the pixel grid of a gonioreflectometer
image, with independent Gaussian noise of standard deviation
``σ = noise · (peak of that image) + floor``; the truth is stored in the metadata as
``{"truth": {"model": ..., "params": {...}}}`` so reports can compare against it. It is a
check of the inverse machinery, not of the physics (for height-field simulations see
:mod:`brdfscale.synth`).
"""

import jax.numpy as jnp
import numpy as np

from brdfscale import InvalidInputError, LobeImage, MeasurementSet
from brdfscale.choices import MIN_FIT_SCALES

from ._data import Dataset
from ._model import predict_images
from ._parametric import ParametricModel


__all__ = ["simulate"]


def simulate(
    model: ParametricModel,
    params: dict,
    scales,
    *,
    size: int = 32,
    extent: float = 0.5,
    noise: float = 0.01,
    floor: float = 1e-3,
    replicates: int = 1,
    seed: int = 0,
) -> MeasurementSet:
    """Noisy lobe images of ``model`` at ``params`` for every scale in ``scales``.

    Args:
        model: the parametric model that generates the images.
        params: physical parameter values (every free parameter of ``model``).
        scales: the scales μ (at least two distinct).
        size, extent: each image is ``size × size`` pixels over ``[−extent, extent]²``.
        noise: relative noise level (σ as a fraction of each image's peak).
        floor: absolute noise floor added to σ (lobe units).
        replicates: images per scale (different incident directions, same lobe).
        seed: NumPy random seed.
    """
    scales = sorted(float(s) for s in scales)
    if len(set(scales)) < MIN_FIT_SCALES:  # before the images are made (fitting.Dataset's minimum)
        raise InvalidInputError(f"simulate needs at least {MIN_FIT_SCALES} distinct scales; got {scales}.")
    if noise < 0 or floor <= 0:
        raise InvalidInputError(f"need noise ≥ 0 and floor > 0; got noise={noise}, floor={floor}.")
    rng = np.random.default_rng(seed)
    incidents = [np.array([np.sin(t), 0.0, np.cos(t)]) for t in np.linspace(0.0, 0.5, replicates)]
    blank = [
        LobeImage(mu=mu, incident=inc, extent=extent, values=np.zeros((size, size)), sigma=np.ones((size, size)))
        for mu in scales
        for inc in incidents
    ]
    data = Dataset.from_measurements(MeasurementSet(tuple(blank)))
    clean = np.asarray(predict_images(model, jnp.asarray(model.theta_from(params)), data))
    images = []
    for i, img in enumerate(blank):
        v = clean[i, : size * size].reshape(size, size)
        sigma = np.full_like(v, noise * v.max() + floor)
        images.append(
            LobeImage(
                mu=img.mu,
                incident=img.incident,
                extent=extent,
                values=v + sigma * rng.standard_normal(v.shape),
                sigma=sigma,
            )
        )
    truth = {
        "model": {"kind": "parametric", "lobe": model.lobe, "statistics": model.statistics},
        "params": {k: float(v) for k, v in params.items()},
    }
    return MeasurementSet(tuple(images), metadata={"truth": truth})
