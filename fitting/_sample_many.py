"""Many posteriors sampled at once: NUTS or HMC vmapped over materials, one compiled program per bucket.

:func:`fitting.sample` with NUTS or HMC already runs a material's chains side by side, one
``jax.vmap`` over the chains inside one compiled loop over the steps of a chunk
(:mod:`fitting._sample_blackjax`). :func:`sample_many` adds a second axis, the materials:

1. every material's posterior is the one :func:`fitting.sample` draws from — ``log p(ζ) =
   log p(θ(z₀ + Bζ) | data) + Σ log dθ/dz`` (:mod:`fitting._posterior`) — the very same
   :class:`~fitting._posterior.Target` (:func:`fitting._posterior.target` of its Problem and
   fit: the determined subspace, and the residual rows padded at zero weight to
   :func:`fitting._batch.bucket_points` points per scale, :func:`~fitting._posterior.padded_rows`),
   with the same starts (:func:`fitting._sample_blackjax.starts`: Laplace draws with
   ``np.random.default_rng(seed)``) and the same keys (``PRNGKey(seed)``; step i of its chains
   ``split(fold_in(key, i), chains)``);
2. the materials are **bucketed** by what the compiled program depends on: the key of
   :func:`fitting.fit_many` (the model's static structure, the numbers of scales, θ
   coordinates and prior rows, the rung of points per scale) and the sampled dimension
   m = d − k (not padded: another m is another bucket; rungs are not merged);
3. a bucket's Targets and chain states are stacked along a leading material axis (padded to
   the rung :func:`fitting._batch.bucket_batch`, rounded up to a whole number per device, with
   copies of its first material whose results are dropped) and advanced chunk by chunk by the
   loop of :func:`fitting.sample` (:meth:`_Gradient.drive`) calling
   :func:`fitting._sample_blackjax._advance` — and :func:`~fitting._sample_blackjax._window_warmup`
   with ``adapt_mass_matrix=True`` — ``jax.vmap``-ed over the materials inside one
   ``eqx.filter_jit``: one compiled program per bucket shape for the warm-up and every chunk.
   Over several devices the stack is divided by the one mechanism of :func:`fitting.fit_many`
   (:mod:`fitting._devices`): each device advances its own contiguous slice of the materials
   with the same program, dispatched device by device, its NUTS trees not waiting for another
   device's, and the outputs are one global array divided over the devices;
4. each material's chain gets the diagnostics of :func:`fitting.sample`: the same
   :class:`~fitting.SampleResult` layout, R̂/ESS, status.

**What is equal.** Each material gets the same Target, starts, keys, kernels, warm-up length
and steps as ``fitting.sample`` with the same arguments (``steps=None`` resolved by the one
:meth:`~fitting._sampler.AbstractSampler.steps_of`). On one device its chain, log-densities,
statistics, warm-up record and hence diagnostics and status are bit for bit ``sample``'s where
XLA computes the vmapped stack of materials as it computes one — the parametric models
(tests/test_sample_many.py: NUTS and HMC with window adaptation, ragged data, materials of
different m; tests/test_library.py: ``brdfscale fit-library --model parametric``). XLA may
rewrite a stacked program's arithmetic: for the anisotropic model (the default) it turns the
Gaussian density's division by each material's determinant into a multiplication by its
reciprocal, so the chains agree to rounding (within 1e-10 over 40 steps, log-densities within
1e-12 relative, the same trajectory lengths: tests/test_sample_many_models.py) and, as over
several devices below, a long chain can part from ``sample``'s where a rounding difference
flips an accept or U-turn decision. (Padding is why ``sample`` evaluates on padded
rows too: zero rows add exactly 0 to χ², but a longer sum rounds differently — on unpadded
rows the chains differed at rounding level, and that was enough to change the rank-normalised
R̂, whose folded draws tie at the median in one run and not in the other, in its third digit.)
Divided over several devices, the per-device program is compiled apart and the log-density's
gradient differs in the last bits: the chains agree to rounding (within 1e-9 over 60 steps on 2
virtual CPU devices, the slow test of tests/test_sample_many.py), diagnostics to rounding except
where R̂'s ranks tie; a long chain can part from ``sample``'s where a rounding difference flips an
accept or U-turn decision, each still a chain of the same posterior.

**Vmapped NUTS.** Within a device the materials' trees are built together: a material whose
trajectory has ended waits (masked) for the longest one, as NUTS's chains already do;
fixed-length HMC with fixed step sizes advances them in lock step.

No checkpoints: resumability in a library is per material (:func:`fitting.sample` with
``checkpoint=``), and a rerun with the same seed draws the same chains.
"""

from typing import cast

import equinox as eqx
import jax
import numpy as np

from brdfscale import InvalidInputError
from brdfscale.checks import flag, integer
from brdfscale.choices import SAMPLE
from brdfscale.show import progress_bar, progress_mode

from ._batch import _key, bucket_batch
from ._devices import assembled, device_list, on_devices, split
from ._posterior import target
from ._problem import check_fit, Problem, stack_trees
from ._sample import _diagnose, resolve_sampler, sampled_dimension
from ._sample_blackjax import (
    _advance,
    _blackjax,
    _Gradient,
    _host,
    _initial_carry,
    _window_warmup,
    join,
    starts,
)


__all__ = ["sample_many"]


@eqx.filter_jit
def _initial_local(targets, z0, cov):
    """:func:`fitting._sample_blackjax._initial_carry` of every material of a stack (one device's)."""
    return jax.vmap(_initial_carry)(targets, z0, cov)


@eqx.filter_jit
def _advance_local(targets, spec, carry, start, n, key, warmup, chunk):
    """:func:`fitting._sample_blackjax._advance` vmapped over the materials of a stack (its
    outputs with the materials first); every material uses ``key``, as :func:`fitting.sample`
    with the same seed does."""
    return jax.vmap(lambda t1, c1: _advance(t1, spec, c1, start, n, key, warmup, chunk))(targets, carry)


@eqx.filter_jit
def _window_local(targets, spec, carry, key, warmup):
    """:func:`fitting._sample_blackjax._window_warmup` vmapped over the materials of a stack."""
    return jax.vmap(lambda t1, c1: _window_warmup(t1, spec, c1, key, warmup))(targets, carry)


def _initial_many(targets, z0, cov, devices):
    """:func:`_initial_local` on every device's slice of the stack (``targets`` a :class:`~fitting._devices.Split`)."""
    return assembled(on_devices(_initial_local, (targets, split(z0, devices), split(cov, devices)), devices), devices)


def _advance_many(targets, spec, carry, start, n, key, warmup, chunk, devices):
    """:func:`_advance_local` on every device's slice of the stack, the outputs one array divided over them."""
    return assembled(
        on_devices(
            lambda t, c: _advance_local(t, spec, c, start, n, key, warmup, chunk),
            (targets, split(carry, devices)),
            devices,
        ),
        devices,
    )


def _window_many(targets, spec, carry, key, warmup, devices):
    """:func:`_window_local` on every device's slice of the stack."""
    return assembled(
        on_devices(lambda t, c: _window_local(t, spec, c, key, warmup), (targets, split(carry, devices)), devices),
        devices,
    )


def _bound(program, targets, spec, devices):
    """``program`` (:func:`_advance_many`, :func:`_window_many`) with the signature :meth:`_Gradient.drive`
    calls (the host carry divided over the devices as the materials are)."""
    return lambda carry, *args: program(targets, spec, carry, *args, devices)


def _pairs(problems, fits) -> tuple[list, list]:
    if isinstance(problems, Problem):
        raise InvalidInputError(
            "sample_many(problems, fits) takes a sequence of problems; for one problem use "
            "fitting.sample(problem, fit)."
        )
    try:
        problems, fits = list(problems), list(fits)
    except TypeError:
        raise InvalidInputError(
            "sample_many needs a sequence of fitting.Problem and a sequence of their "
            "FitResults (e.g. from fitting.fit_many)."
        ) from None
    if not problems:
        raise InvalidInputError("sample_many needs at least one problem.")
    if len(problems) != len(fits):
        raise InvalidInputError(f"problems and fits must pair up: got {len(problems)} problems and {len(fits)} fits.")
    return problems, fits


def sample_many(
    problems,
    fits,
    *,
    sampler=SAMPLE.batched_sampler,
    chains: int = SAMPLE.chains,
    steps: int | None = SAMPLE.steps,
    chunk: int = SAMPLE.chunk,
    seed: int = SAMPLE.seed,
    batch: int = 64,
    devices=None,
    progress: bool = False,
    errors: str = "raise",
) -> list:
    """Sample many posteriors at once: :func:`fitting.sample` with NUTS or HMC for every
    ``(problem, fit)`` pair, vmapped over the materials in one compiled program per bucket and
    divided over the devices (module docstring).

    Each material's :class:`~fitting.SampleResult` is that of ``fitting.sample(problem, fit,
    sampler=sampler, chains=chains, steps=steps, chunk=chunk, seed=seed)``: the same starts,
    keys, warm-up and draws — bit for bit on one device where XLA compiles the stacked program's
    arithmetic as the single one's (the parametric models), so the same diagnostics and status;
    to rounding for the anisotropic model and when divided over several devices (module
    docstring, "What is equal"; verified in tests/test_sample_many.py and
    tests/test_sample_many_models.py) — in the same layout.

    There are no checkpoints: resumability in a library is per material (:func:`fitting.sample`
    with ``checkpoint=``); rerunning is deterministic by the seed.

    Args:
        problems: a sequence of :class:`~fitting.Problem`.
        fits: their :class:`~fitting.FitResult`, in the same order (e.g. from
            :func:`fitting.fit_many`).
        sampler: ``"nuts"`` (default), ``"hmc"``, or a :class:`fitting.NUTS` /
            :class:`fitting.HMC` object with its settings (as for :func:`fitting.sample`).
        chains, steps, chunk, seed: as for :func:`fitting.sample`, for every material (each
            material's seed is ``seed``, so each gets the chains ``sample`` would give it).
        batch: at most this many materials per compiled program run (≥ 1; default 64).
        devices: ``None`` (every device of ``jax.devices()``), a count (the first ones), or a
            list of ``jax.Device``; the material axis is divided over them.
        progress: one progress bar over the steps of every bucket in turn.
        errors: ``"raise"`` (default): a material that cannot be sampled (the data determine
            none of its coordinates) raises, naming its index; ``"return"``: its entry is the
            :class:`~brdfscale.InvalidInputError` instead, and the others are kept — as is a
            fit entry that is itself the InvalidInputError of ``fit_many(…, errors="return")``.

    Returns:
        A list with a :class:`~fitting.SampleResult` (or, with ``errors="return"``, an
        :class:`~brdfscale.InvalidInputError`) per material, in the order of ``problems``. Its
        ``timing`` is its bucket's warm-up and sampling seconds divided by the bucket's number
        of materials (compilation included on a bucket shape's first run).

    Raises:
        InvalidInputError: emcee (its ensembles step on the host, they do not vectorise across
            materials: use :func:`fitting.sample` per material); an unknown sampler; problems
            and fits that do not pair up, or a fit that is not its problem's (naming the
            material); the arguments of :func:`fitting.sample` out of range; ``batch`` not an
            integer ≥ 1, ``devices`` as for :func:`fitting.fit_many`, ``errors`` not
            ``"raise"``/``"return"``; with ``errors="raise"``, a material that cannot be sampled.
        MissingDependencyError: BlackJAX is not installed.
    """
    problems, fits = _pairs(problems, fits)
    chosen = resolve_sampler(sampler)
    chosen.check_batched()  # emcee refuses, naming why
    sampler = cast("_Gradient", chosen)  # NUTS or HMC: the samplers that run vmapped over materials
    chains = integer(chains, "chains", 1)
    steps = integer(sampler.steps_of(steps), "steps", 2)
    chunk = integer(chunk, "chunk", 1)
    seed = integer(seed, "seed", 0)
    batch = integer(batch, "batch", 1)
    progress = flag(progress, "progress")
    if progress:
        progress_mode()  # a BRDFSCALE_PROGRESS it does not accept is refused before any work
    if errors not in ("raise", "return"):
        raise InvalidInputError(f"errors must be 'raise' or 'return'; got {errors!r}.")
    _blackjax()
    devices = device_list(devices)

    results: list = [None] * len(problems)
    groups: dict = {}  # bucket key → (m, materials), in the order of first appearance
    for i, (problem, fit) in enumerate(zip(problems, fits)):
        what = f"sample_many: material {i}"
        if isinstance(fit, InvalidInputError) and errors == "return":
            results[i] = InvalidInputError(f"{what}: its fit failed: {fit}")
            continue
        check_fit(problem, fit, what)  # arguments that do not belong together: always refused
        try:
            m = sampled_dimension(problem, fit, what)
        except InvalidInputError as err:
            if errors == "raise":
                raise
            results[i] = err
            continue
        rows = problem.rows()
        shape = _key(rows, int(rows.points.mean.shape[1])) + (m,)
        groups.setdefault(shape, (m, []))[1].append(i)
    buckets = [(m, members[k : k + batch]) for m, members in groups.values() for k in range(0, len(members), batch)]

    spec, total = sampler._spec(), sampler.warmup + steps
    key = jax.random.PRNGKey(seed)
    n_dev = len(devices)

    with progress_bar(
        enabled=progress, total=total * len(buckets), desc=f"sample_many ({sampler.name})", unit="step"
    ) as bar:
        for m, members in buckets:
            # each material's Target is sample's: its rows padded to the bucket's points (padded_rows)
            posteriors = [target(problems[i], fits[i]) for i in members]
            z0, cov = zip(*(starts(post, fits[i], chains, seed) for post, i in zip(posteriors, members)))
            size = -(-bucket_batch(len(members), batch) // n_dev) * n_dev
            extra = size - len(members)
            targets = split(stack_trees(posteriors + posteriors[:1] * extra), devices)
            z0 = np.stack(z0 + z0[:1] * extra)
            cov = np.stack(cov + cov[:1] * extra)
            carry = _host(_initial_many(targets, z0, cov, devices))
            timing = {"warmup_s": 0.0, "sampling_s": 0.0}
            carry, blocks = sampler.drive(
                _bound(_window_many, targets, spec, devices),
                _bound(_advance_many, targets, spec, devices),
                carry,
                0,
                total,
                chunk,
                key,
                timing,
                bar.update,
                lambda block, c: None,
                axis=1,
            )
            chain, log_prob, stats = join(blocks, axis=1)
            share = {k: v / len(members) for k, v in timing.items()}
            for j, (i, post) in enumerate(zip(members, posteriors)):
                own = {k: v[j].copy() for k, v in stats.items()}
                record = sampler.warmup_record({k: v[j].copy() for k, v in carry.items()}, own["acceptance_rate"])
                try:
                    results[i] = _diagnose(
                        post,
                        fits[i],
                        sampler,
                        sampler.settings(m),
                        chains,
                        chain[j].copy(),
                        log_prob[j].copy(),
                        own,
                        record,
                        dict(share),
                    )
                except InvalidInputError as err:
                    if errors == "raise":
                        raise InvalidInputError(f"sample_many: material {i}: {err}") from None
                    results[i] = err
    return results
