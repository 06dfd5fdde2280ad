"""Derived quantities: the model's physical quantities and the ratios ``S(W, μ0)/S(W, μ_k)``
at θ and at draws of θ — the one place every result, report, figure and sampler computes them.

* :func:`quantity_names` — the names of ``model.quantities``, in the model's order;
* :func:`quantities_at` — the quantities at a stack of θ (posterior draws, Laplace draws), name
  → array, in the model's order (one compiled ``jax.vmap``);
* :func:`ratio_frequencies`, :func:`ratio_names` — where the ratios are reported;
* :func:`evaluate`, :func:`evaluate_many` — quantities and ratios at θ̂, their Jacobians there
  and their values at the Laplace draws, for one material or a stack (what
  :mod:`fitting._analysis` summarises).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._data import Dataset
from ._model import moments


__all__ = [
    "RATIO_FREQUENCIES",
    "evaluate",
    "evaluate_many",
    "quantities_at",
    "quantity_names",
    "quantity_vector",
    "ratio_frequencies",
    "ratio_names",
]


def quantity_names(model) -> list:
    """The names of ``model.quantities``, in its order (from an abstract evaluation: no
    computation; not from ``eval_shape``'s output, a dict that comes back with sorted keys)."""
    names = []

    def capture(t):
        quantities = model.quantities(t)
        names.extend(quantities)
        return jnp.stack(list(quantities.values()))

    jax.eval_shape(capture, jax.ShapeDtypeStruct((len(model.names),), jnp.float64))
    return names


def quantity_vector(model, theta):
    """``model.quantities(θ)`` as one vector, in the order of :func:`quantity_names`."""
    return jnp.stack(list(model.quantities(theta).values()))


@eqx.filter_jit
def _quantity_draws(model, thetas):
    return jax.vmap(lambda t: quantity_vector(model, t))(thetas)


def quantities_at(model, thetas) -> dict:
    """The model's quantities at every θ of ``thetas`` (…, d): name → NumPy array (…), in the
    model's order (:func:`quantity_names`)."""
    thetas = jnp.asarray(thetas)
    flat = np.asarray(_quantity_draws(model, thetas.reshape(-1, thetas.shape[-1])))
    return {name: flat[:, i].reshape(thetas.shape[:-1]) for i, name in enumerate(quantity_names(model))}


RATIO_FREQUENCIES = (0.5, 1.0, 2.0)
"""The frequencies |W| at which the ratios ``S(W, μ0)/S(W, μ_k)`` are reported, in units of
``1/α``, α the half-maximum width of the widest (coarsest-scale) images: there every scale's
lobe transform is still well above the noise (``≈ e^{−1/16}, e^{−1/4}, e^{−1}`` of its peak for
a Beckmann lobe), so the ratio ``G(W, μ_k)/G(W, μ0)`` is what the images measure."""


def ratio_frequencies(data: Dataset) -> np.ndarray:
    """The reported ratios' frequencies |W| for this dataset (:data:`RATIO_FREQUENCIES` / α)."""
    _, width2 = moments(data)
    return np.asarray(RATIO_FREQUENCIES) / np.sqrt(max(float(np.max(width2)), 1e-300))


def ratio_names(data: Dataset, W) -> list[str]:
    """``"S(μ0)/S(μk) @ |W|=w"`` for every coarser scale k and frequency w."""
    return [f"S(μ0)/S(μ{k}) @ |W|={w:.4g}" for k in range(1, len(data.scales)) for w in np.asarray(W)]


def _evaluation(model, theta, draws, W, scales):
    """The quantities and the ratios ``S(W, μ0)/S(W, μ_k)``, k ≥ 1 (flattened), each at θ̂, their
    Jacobian there, and at every Laplace draw."""

    def quantities(t):
        return quantity_vector(model, t)

    def ratios(t):
        return model.relative_statistics(t, W, scales)[1:].ravel()

    return (
        quantities(theta),
        jax.jacfwd(quantities)(theta),
        jax.vmap(quantities)(draws),
        ratios(theta),
        jax.jacfwd(ratios)(theta),
        jax.vmap(ratios)(draws),
    )


evaluate = eqx.filter_jit(_evaluation)
"""Quantities and ratios at θ̂, their Jacobians and their values at the draws: ``(model, θ̂,
draws, W, scales) → (q, ∂q/∂θ, q(draws), r, ∂r/∂θ, r(draws))``."""

evaluate_many = eqx.filter_jit(jax.vmap(_evaluation))
""":func:`evaluate` of a stack of materials of one structure (every argument stacked)."""
