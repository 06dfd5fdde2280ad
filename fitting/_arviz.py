"""A :class:`fitting.SampleResult` as ArviZ data (``SampleResult.to_arviz``; ArviZ is the optional extra ``brdfscale[mcmc]``).

The installed ArviZ (0.x) holds runs as ``arviz.InferenceData``; ArviZ ≥ 1.0 replaced it by
an ``xarray.DataTree`` with the same groups, which this converter returns there. Layout:

* ``posterior``: ``theta`` (chain, draw, coordinate) — the model's coordinates θ, labelled by
  their names — and ``quantities`` (chain, draw, quantity) — the model's physical quantities
  (``model.quantities(θ)``), after the burn-in (warm-up) steps;
* ``sample_stats``: ``lp`` (log p(θ | data) = −½χ²(θ) + const) and, for NUTS/HMC,
  ``acceptance_rate``, ``diverging``, ``n_steps`` (leapfrog steps), ``step_size``;
* ``warmup_posterior``, ``warmup_sample_stats``: the same for the discarded steps;
* attributes (of the data and of its ``posterior`` group): the sampler, its settings (JSON),
  the independent chains, the trajectories per chain, the burn-in, the prior and the sampling
  coordinates (``sampling_coordinates``: NetCDF's conventions reserve ``coordinates``).

ArviZ's "chain" is a trajectory: one chain of NUTS/HMC, one walker of emcee (as
``arviz.from_emcee`` has it; walker ``w`` belongs to ensemble ``w // walkers``).
"""

import json

import numpy as np

from brdfscale import MissingDependencyError

__all__ = ["to_arviz", "arviz"]

_STAT_NAMES = {"acceptance_rate": "acceptance_rate", "divergent": "diverging", "integration_steps": "n_steps",
               "step_size": "step_size"}


def arviz():
    """ArviZ, or :class:`brdfscale.MissingDependencyError` naming the extra that brings it."""
    try:
        import arviz as az
    except ImportError as err:
        raise MissingDependencyError(
            "SampleResult.to_arviz needs ArviZ, the optional extra brdfscale[mcmc]: pip install \"brdfscale[mcmc]\" "
            "(the diagnostics of SampleResult.summary() and its status need no ArviZ); the import failed: "
            f"{err}") from None
    return az


def _groups(result, part):
    """posterior and sample_stats dicts (chain, draw, …) of the steps ``part`` (a slice)."""
    theta = np.swapaxes(result.chain[part], 0, 1)
    posterior = {"theta": theta}
    if result.quantities:
        posterior["quantities"] = np.swapaxes(np.stack(list(result.quantities.values()), axis=-1)[part], 0, 1)
    stats = {"lp": np.swapaxes(result.log_prob[part], 0, 1)}
    for name, values in result.stats.items():
        v = np.swapaxes(values[part], 0, 1)
        stats[_STAT_NAMES.get(name, name)] = v.astype(bool) if name == "divergent" else v
    return posterior, stats


def to_arviz(result):
    """The run as ArviZ data (module docstring)."""
    az = arviz()
    burn = result.burn
    posterior, stats = _groups(result, slice(burn, None))
    coords = {"coordinate": list(result.names)}
    dims = {"theta": ["coordinate"]}
    if result.quantities:
        coords["quantity"] = list(result.quantities)
        dims["quantities"] = ["quantity"]
    attrs = {"sampler": result.sampler, "sampler_settings": json.dumps(result.settings, sort_keys=True, default=str),
             "independent_chains": int(result.chains),
             "trajectories_per_chain": int(result.chain.shape[1] // max(result.chains, 1)),
             "burn_in": int(burn), "prior": result.prior,
             "sampling_coordinates": result.coordinates}  # not "coordinates": CF conventions reserve it
    extra = {}
    if burn > 0:
        warm_posterior, warm_stats = _groups(result, slice(0, burn))
        extra = {"warmup_posterior": warm_posterior, "warmup_sample_stats": warm_stats, "save_warmup": True}
    data = az.from_dict(posterior=posterior, sample_stats=stats, coords=coords, dims=dims, attrs=attrs, **extra)
    data.posterior.attrs.update(attrs)  # the group's attributes travel with it (NetCDF, DataTree)
    return data
