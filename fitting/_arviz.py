"""A :class:`fitting.SampleResult` as ArviZ data (``SampleResult.to_arviz``; ArviZ is the optional
extra ``brdfscale[mcmc]``).

The installed ArviZ (0.x) holds runs as ``arviz.InferenceData``; ArviZ ≥ 1.0 replaced it by
an ``xarray.DataTree`` with the same groups, which this converter returns there. Layout, as
ArviZ's own converters (``from_numpyro``, ``from_pymc``) have it — one variable per quantity:

* ``posterior``: one variable (chain, draw) per coordinate θ, named by the model
  (``"log amplitude"``, …), and one per quantity the fit determines (``"amplitude"``, …;
  ``model.quantities(θ)``; a quantity with the name of a coordinate is left out), after the
  burn-in (warm-up) steps — so ``arviz.summary(data, var_names=["amplitude"])`` and
  ``arviz.plot_trace(data, var_names=[…])`` work;
* ``sample_stats``: ``lp`` (log p(θ | data) = −½χ²(θ) + const) and, for NUTS/HMC,
  ``acceptance_rate``, ``diverging``, ``n_steps`` (leapfrog steps), ``step_size``;
* ``warmup_posterior``, ``warmup_sample_stats``: the same for the discarded steps;
* attributes (of the data and of its ``posterior`` group): the sampler, its settings (JSON),
  the independent chains, the walkers per chain (emcee; 1 for NUTS/HMC), the burn-in, the
  prior and the sampling coordinates (``sampling_coordinates``: NetCDF's conventions reserve
  ``coordinates``).

ArviZ's "chain" is an independent chain: one chain of NUTS/HMC, or one of emcee's
independent ensembles, whose draws are its walkers' trajectories one after another
(:meth:`fitting.SampleResult.by_chain`) — R̂ compares the ensembles, which started apart and
never exchange information, and no warning of "more chains than draws" arises from counting
walkers as chains. ``arviz.summary`` of the data gives the figures of
:meth:`fitting.SampleResult.summary`.
"""

from brdfscale import MissingDependencyError
from brdfscale.files import json_text


__all__ = ["arviz", "to_arviz"]

_STAT_NAMES = {
    "acceptance_rate": "acceptance_rate",
    "divergent": "diverging",
    "integration_steps": "n_steps",
    "step_size": "step_size",
}


def arviz():
    """ArviZ, or :class:`brdfscale.MissingDependencyError` naming the extra that brings it."""
    try:
        import arviz as az
    except ImportError as err:
        raise MissingDependencyError(
            'SampleResult.to_arviz needs ArviZ, the optional extra brdfscale[mcmc]: pip install "brdfscale[mcmc]" '
            "(the diagnostics of SampleResult.summary() and its status need no ArviZ); the import failed: "
            f"{err}"
        ) from None
    return az


def _groups(result, part):
    """posterior and sample_stats dicts (chain, draw) of the steps ``part`` (a slice)."""
    posterior = {name: result.by_chain(result.chain[part, :, i]) for i, name in enumerate(result.names)}
    for name, values in (result.quantities or {}).items():
        if name not in posterior and (result.determined is None or name in result.determined):
            posterior[name] = result.by_chain(values[part])
    stats = {"lp": result.by_chain(result.log_prob[part])}
    for name, values in result.stats.items():
        v = result.by_chain(values[part])
        stats[_STAT_NAMES.get(name, name)] = v.astype(bool) if name == "divergent" else v
    return posterior, stats


def to_arviz(result):
    """The run as ArviZ data (module docstring)."""
    az = arviz()
    burn = result.burn
    posterior, stats = _groups(result, slice(burn, None))
    attrs = {
        "sampler": result.sampler,
        "sampler_settings": json_text(result.settings, other=str, sort_keys=True),
        "independent_chains": int(result.chains),
        "walkers_per_chain": int(result.walkers),
        "burn_in": int(burn),
        "prior": result.prior,
        "sampling_coordinates": result.coordinates,
    }  # not "coordinates": CF conventions reserve it
    extra = {}
    if burn > 0:
        warm_posterior, warm_stats = _groups(result, slice(0, burn))
        extra = {"warmup_posterior": warm_posterior, "warmup_sample_stats": warm_stats, "save_warmup": True}
    data = az.from_dict(posterior=posterior, sample_stats=stats, attrs=attrs, **extra)
    data["posterior"].attrs.update(attrs)  # the group's attributes travel with it (NetCDF, DataTree)
    return data
