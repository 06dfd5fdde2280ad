"""BlackJAX's gradient-based kernels for :func:`fitting.sample`: NUTS and fixed-length HMC, all chains in one program.

Both draw ζ — the coordinates of the determined subspace of the smooth coordinates z — from
:meth:`fitting._posterior.Target.log_density` (the posterior of θ, Jacobian included),
preconditioned by the Laplace covariance in ζ (:func:`fitting._posterior.laplace`) as inverse
mass matrix. ``chains`` chains start from
independent draws of that Laplace approximation (over-dispersed enough for R̂ to compare
chains that started apart) and run side by side: every transition of every chain is one
``jax.vmap`` inside one compiled ``jax.lax.fori_loop`` over the steps of a chunk — the same
compiled program for the warm-up and the draws, for every chunk (its trip count is an
argument, its output buffers have the chunk's length).

Warm-up (``warmup`` steps, kept in the chain and discarded as burn-in):

* ``adapt_mass_matrix=False`` (default): the mass matrix stays the Laplace covariance; the
  step size of each chain is tuned by BlackJAX's dual averaging (Hoffman & Gelman 2014,
  target ``target_acceptance``) during the warm-up, then fixed at its averaged value.
  Chunked and checkpointed like the draws.
* ``adapt_mass_matrix=True``: BlackJAX's ``window_adaptation`` (Stan's windows: step size
  and a dense inverse mass matrix estimated from the chain's own draws, seeded with the
  Laplace covariance), per chain, in one program; the checkpoint stores its result after
  the warm-up (an interruption during it repeats the warm-up, with the same result).

Randomness: step i (warm-up included) of all chains uses ``jax.random.split(fold_in(key, i),
chains)``, ``key = jax.random.PRNGKey(seed)``: a step's key depends on its index only, so a run
resumed from a checkpoint (which stores the chains' positions, log-densities, gradients,
dual-averaging states and mass matrices) draws exactly what the uninterrupted run draws.
"""

import abc
import dataclasses
import functools
import math
import time
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import InvalidInputError, MissingDependencyError
from brdfscale.checks import flag, integer, real
from brdfscale.choices import SAMPLE
from brdfscale.show import progress_bar

from ._checkpoint import resumed_blocks
from ._posterior import covariance_root, initial_positions, laplace
from ._sampler import AbstractSampler, out_of_time, paced


__all__ = ["HMC", "NUTS"]

_STATS = {"acceptance_rate": "f8", "divergent": "u1", "integration_steps": "i8", "step_size": "f8"}
_INITIAL_STEP_SIZE = 1.0  # in the coordinates the Laplace mass matrix whitens: about right for a Gaussian
_MAX_HMC_STEPS = 1024  # NUTS's longest trajectory at max_doublings = 10


def _blackjax():
    """BlackJAX, imported on first use (importing brdfscale.fitting stays light); a
    :class:`brdfscale.MissingDependencyError` where it is not installed."""
    try:
        import blackjax
        import blackjax.adaptation.step_size  # loaded by blackjax's own imports; named for the type checker
    except ImportError as err:
        raise MissingDependencyError(
            "fitting.NUTS and fitting.HMC need BlackJAX (a dependency of brdfscale on Python ≥ 3.11: pip install "
            f'"blackjax>=1.7.1"); sampler="emcee" needs no BlackJAX. The import failed: {err}'
        ) from None
    return blackjax


class _Gradient(AbstractSampler):
    """What NUTS and HMC share: validation, the checkpoint's record, the run."""

    warmup: int
    target_acceptance: float
    adapt_mass_matrix: bool
    # NUTS and HMC are (frozen) dataclasses, as every sampler is (fitting._sampler): settings() lists their fields
    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field]]

    @abc.abstractmethod
    def _spec(self) -> tuple:
        """The kernel's static description: (kind, max_doublings, trajectory_length, jitter, target acceptance)."""

    stats = _STATS
    # Laplace-preconditioned on a near-Gaussian posterior, a transition is nearly an independent draw: a
    # thousand draws per chain give ESS_bulk far above 400 and keep R̂ ≤ 1.01 (at 500 it reached 1.010 on
    # one seed of the benchmark's set: R̂, not the ESS, decides how many; docs/fitting.md measures both)
    default_steps = SAMPLE.steps_for("nuts")  # and HMC

    def _check_common(self):
        object.__setattr__(self, "warmup", integer(self.warmup, "warmup", 0))
        object.__setattr__(
            self, "target_acceptance", real(self.target_acceptance, "target_acceptance", minimum=0.0, strict=True)
        )
        if not self.target_acceptance < 1:
            raise InvalidInputError(f"target_acceptance must lie in (0, 1); got {self.target_acceptance}.")
        object.__setattr__(self, "adapt_mass_matrix", flag(self.adapt_mass_matrix, "adapt_mass_matrix"))
        if self.adapt_mass_matrix and self.warmup < 20:
            raise InvalidInputError(
                f"adapt_mass_matrix=True needs warmup ≥ 20 steps (Stan's windows); got {self.warmup}."
            )

    def settings(self, d: int) -> dict:
        return {"name": self.name, **dataclasses.asdict(self)}

    def trajectories(self, d: int, chains: int) -> int:
        return chains

    def burn_in(self, chain, warmup):
        """The warm-up steps (at most the chain's length); the warm-up record as :meth:`run` made it."""
        return min(self.warmup, chain.shape[0]), warmup

    def warmup_text(self) -> str:
        if self.adapt_mass_matrix:
            return (
                "BlackJAX window_adaptation per chain (Stan's windows: step size and dense inverse mass matrix, "
                "seeded with the Laplace covariance)"
            )
        return (
            f"dual averaging of each chain's step size (target acceptance {self.target_acceptance:g}); inverse "
            "mass matrix fixed at the Laplace covariance"
        )

    def total(self, steps: int) -> int:
        """The warm-up and the draws."""
        return self.warmup + steps

    def run(self, target, fit, *, chains, steps, seed, store, resumed, progress, chunk, deadline=None):
        """The chain (warmup + steps, chains, d) in θ, log_prob, per-step statistics and the
        warm-up record; resumed from ``resumed`` where it holds steps, each chunk appended to ``store``;
        ended early, after the warm-up, where :func:`fitting._sampler.out_of_time` says so for ``deadline``."""
        _blackjax()  # a missing BlackJAX is named before any work
        total = self.warmup + steps
        spec = self._spec()
        blocks, carry = resumed_blocks(resumed, total)
        if carry is None:
            z0, cov = starts(target, fit, chains, seed)
            carry = _host(_initial_carry(target, jnp.asarray(z0), jnp.asarray(cov)))
        done = blocks[0][0].shape[0] if blocks else 0
        timing = {"warmup_s": 0.0, "sampling_s": 0.0}  # this call's computing (checkpoint writes excluded)
        commit = (lambda block, c: None) if store is None else (lambda block, c: store.append(*block, c))
        with progress_bar(enabled=progress, total=total, initial=min(done, total), desc=self.name, unit="step") as bar:
            carry, more = self.drive(
                functools.partial(_window_warmup, target, spec),
                functools.partial(_advance, target, spec),
                carry,
                done,
                total,
                chunk,
                jax.random.PRNGKey(seed),
                timing,
                bar.update,
                commit,
                deadline=deadline,
            )
        chain, log_prob, stats = join(blocks + more)
        return chain, log_prob, stats, self.warmup_record(carry, stats["acceptance_rate"]), timing

    def drive(self, window, advance, carry, done, total, chunk, key, timing, update, commit, axis=0, deadline=None):
        """Steps ``done … total − 1`` of the chains from ``carry``, chunk by chunk: the warm-up
        (BlackJAX's window adaptation in one call, ``window(carry, key, warmup)``, where
        ``adapt_mass_matrix``), then ``advance(carry, start, n, key, warmup, chunk)`` for
        ``n ≤ chunk`` steps at a time — :func:`_advance` for one material's chains, or a
        function of the same signature over a stack of materials (:func:`fitting.sample_many`,
        whose outputs have the materials first: ``axis=1`` is then the steps' axis). A chunk
        ends where the warm-up does (its time is reported apart); a step's key depends on its
        index only, so the chunking changes no draw. After each call ``commit(block, carry)``
        (the checkpoint) and ``update(steps)`` (the progress bar); the seconds computing are
        added to ``timing``; the loop ends early where :func:`fitting._sampler.out_of_time` says so for
        ``deadline`` (draws after the warm-up). Returns the host carry and the blocks (θ, log p(θ), statistics)."""
        blocks, first = [], done
        if self.adapt_mass_matrix and done < self.warmup:
            started = time.perf_counter()
            carry, block = window(carry, key, self.warmup)
            carry, block = _host(carry), jax.tree_util.tree_map(np.asarray, block)
            timing["warmup_s"] += time.perf_counter() - started
            blocks.append(block)
            commit(block, carry)
            done = self.warmup
            update(self.warmup)
        while done < total and not out_of_time(deadline, done - self.warmup):
            n = min(chunk, total - done, self.warmup - done if done < self.warmup else chunk)
            if done >= self.warmup:  # draws: at the pace of this call's steps so far (the warm-up's for the first)
                spent = timing["warmup_s"] + timing["sampling_s"]
                n = paced(n, deadline, spent, done - first, done - self.warmup)
            steps = (slice(None),) * axis + (slice(0, n),)
            started = time.perf_counter()
            # NumPy in, NumPy out: the carry's dtypes never change (no weak types), so the one
            # compiled program serves every chunk
            carry, out = advance(carry, np.int64(done), np.int64(n), key, np.int64(self.warmup), chunk)
            carry = _host(carry)
            block = jax.tree_util.tree_map(lambda a, steps=steps: np.asarray(a)[steps], out)
            timing["warmup_s" if done < self.warmup else "sampling_s"] += time.perf_counter() - started
            commit(block, carry)
            blocks.append(block)
            done += n
            update(n)
        return carry, blocks

    def warmup_record(self, state, acceptance) -> dict:
        """What the warm-up did, from the chains' host carry after it and their acceptance rates
        (steps, chains): the adapted step sizes and inverse mass matrices."""
        return {
            "kind": self.warmup_text(),
            "steps": self.warmup,
            "step_size": np.exp(state["log_step_size_avg"]).tolist(),
            "inverse_mass_matrix": state["inverse_mass_matrix"],
            "acceptance_rate": float(np.mean(acceptance[: self.warmup])) if self.warmup else None,
        }


def starts(target, fit, chains, seed):
    """The chains' starts ζ (chains, m) — draws of the Laplace approximation in ζ with
    ``np.random.default_rng(seed)`` — and its covariance (the initial inverse mass matrix)."""
    mode, cov = laplace(target, fit)
    return initial_positions(mode, covariance_root(cov), chains, np.random.default_rng(seed)), cov


def join(blocks, axis=0):
    """The blocks (θ, log p(θ), statistics) of :meth:`_Gradient.drive` joined along the steps' ``axis``."""
    return (
        np.concatenate([b[0] for b in blocks], axis=axis),
        np.concatenate([b[1] for b in blocks], axis=axis),
        {k: np.concatenate([b[2][k] for b in blocks], axis=axis) for k in _STATS},
    )


@dataclasses.dataclass(frozen=True)
class NUTS(_Gradient):
    """BlackJAX's NUTS (multinomial, iterative; Laplace-preconditioned), ``chains`` chains vmapped (module docstring).

    Args:
        warmup: warm-up steps per chain (default 100, ``brdfscale.choices.SAMPLE.gradient_warmup``;
            kept in the chain, discarded as burn-in).
        target_acceptance: the dual averaging's target mean acceptance (default 0.8).
        max_doublings: the most trajectory doublings (default 10: at most 1023 leapfrog steps).
        adapt_mass_matrix: False (default) — the Laplace covariance as inverse mass
            matrix throughout; True — Stan's windowed adaptation of a dense one (BlackJAX).
    """

    warmup: int = SAMPLE.gradient_warmup
    target_acceptance: float = 0.8
    max_doublings: int = 10
    adapt_mass_matrix: bool = False
    name = "nuts"

    def __post_init__(self):
        self._check_common()
        object.__setattr__(self, "max_doublings", integer(self.max_doublings, "max_doublings", 1))

    def _spec(self):
        return ("nuts", self.max_doublings, 0, 0.0, self.target_acceptance)


@dataclasses.dataclass(frozen=True)
class HMC(_Gradient):
    """BlackJAX's static HMC: a fixed trajectory length T (in the coordinates the mass matrix
    whitens), Laplace-preconditioned, ``chains`` chains vmapped (module docstring). Each
    transition takes ``L = min(⌈T/ε⌉, 1024)`` leapfrog steps of the chain's step size ε — the
    same L for every transition once the warm-up has fixed ε, so the chains advance in lock
    step (no waiting for the longest trajectory, as NUTS's vmapped chains do) — with the step
    size then jittered to ``ε·U[1 − jitter, 1 + jitter]``.

    Args:
        trajectory_length: T (default π/2: for a Gaussian the Laplace mass matrix whitens, a
            quarter period, after which a draw is independent of its start; the jitter keeps
            T away from the half and full periods, where fixed-length HMC returns to its start).
        warmup: warm-up steps per chain (default 100, as for :class:`NUTS`).
        target_acceptance: the dual averaging's target acceptance (default 0.8).
        jitter: the step size's relative jitter per transition (default 0.2).
        adapt_mass_matrix: as for :class:`NUTS` (BlackJAX's window adaptation then runs
            ⌈T⌉ steps per transition, without jitter).
    """

    trajectory_length: float = math.pi / 2
    warmup: int = SAMPLE.gradient_warmup
    target_acceptance: float = 0.8
    jitter: float = 0.2
    adapt_mass_matrix: bool = False
    name = "hmc"

    def __post_init__(self):
        self._check_common()
        object.__setattr__(
            self, "trajectory_length", real(self.trajectory_length, "trajectory_length", minimum=0.0, strict=True)
        )
        jitter = real(self.jitter, "jitter", minimum=0.0)
        if not jitter < 1:
            raise InvalidInputError(f"jitter must lie in [0, 1); got {jitter}.")
        object.__setattr__(self, "jitter", jitter)

    def _spec(self):
        return ("hmc", 0, self.trajectory_length, self.jitter, self.target_acceptance)


def _host(carry) -> dict:
    """The carry as NumPy arrays of fixed dtypes (float64 positions and densities, int64 counters)."""
    return {
        k: np.asarray(v, dtype=np.int64 if np.issubdtype(np.asarray(v).dtype, np.integer) else np.float64)
        for k, v in carry.items()
    }


@eqx.filter_jit
def _initial_carry(target, z0, cov):
    """Positions, log-densities and gradients of the chains' starts, a fresh dual averaging, the Laplace matrix."""
    da_init = _blackjax().adaptation.step_size.dual_averaging_adaptation(0.8)[0]  # init needs no target
    value, grad = jax.vmap(jax.value_and_grad(target.log_density))(z0)
    da = jax.vmap(lambda _: da_init(jnp.asarray(_INITIAL_STEP_SIZE, z0.dtype)))(jnp.arange(z0.shape[0]))
    chains = z0.shape[0]
    return {
        "position": z0,
        "logdensity": value,
        "logdensity_grad": grad,
        "log_step_size": da.log_step_size,
        "log_step_size_avg": da.log_step_size_avg,
        "da_step": da.step,
        "avg_error": da.avg_error,
        "mu": da.mu,
        "inverse_mass_matrix": jnp.broadcast_to(cov, (chains,) + cov.shape),
    }


def _transition(spec, logdensity):
    """One transition of one chain:
    ``(key, carry, adapt) → (carry, (z, log-density, acceptance, divergent, steps, ε))``."""
    blackjax = _blackjax()
    kind, max_doublings, trajectory_length, jitter, target = spec
    nuts_kernel, hmc_kernel = blackjax.nuts.build_kernel(), blackjax.hmc.build_kernel()
    da_update = blackjax.adaptation.step_size.dual_averaging_adaptation(target)[1]
    DA = blackjax.adaptation.step_size.DualAveragingAdaptationState
    HMCState = blackjax.mcmc.hmc.HMCState

    def one(key, c, adapt):
        state = HMCState(c["position"], c["logdensity"], c["logdensity_grad"])
        da = DA(c["log_step_size"], c["log_step_size_avg"], c["da_step"], c["avg_error"], c["mu"])
        eps = jnp.exp(jnp.where(adapt, da.log_step_size, da.log_step_size_avg))
        if kind == "nuts":
            new, info = nuts_kernel(key, state, logdensity, eps, c["inverse_mass_matrix"], max_doublings)
        else:
            steps = jnp.clip(jnp.ceil(trajectory_length / eps), 1, _MAX_HMC_STEPS).astype(jnp.int32)
            k_jitter, key = jax.random.split(key)
            eps = eps * jax.random.uniform(k_jitter, (), eps.dtype, 1 - jitter, 1 + jitter)
            new, info = hmc_kernel(key, state, logdensity, eps, c["inverse_mass_matrix"], steps)
        acceptance = jnp.where(jnp.isfinite(info.acceptance_rate), info.acceptance_rate, 0.0)
        updated = da_update(da, acceptance)
        da = jax.tree_util.tree_map(lambda a, b: jnp.where(adapt, a, b), updated, da)
        out = {
            **c,
            "position": new.position,
            "logdensity": new.logdensity,
            "logdensity_grad": new.logdensity_grad,
            "log_step_size": da.log_step_size,
            "log_step_size_avg": da.log_step_size_avg,
            "da_step": da.step,
            "avg_error": da.avg_error,
            "mu": da.mu,
        }
        return out, (new.position, new.logdensity, acceptance, info.is_divergent, info.num_integration_steps, eps)

    return one


def _record(target, zeta, logdensity):
    """θ and log p(θ | data) of the samplers' positions ζ with their log-density."""
    return target.theta(zeta), target.log_prob_theta(zeta, logdensity)


@eqx.filter_jit
def _advance(target, spec, carry, start, n, key, warmup, chunk):
    """Steps ``start … start + n − 1`` of every chain (``n ≤ chunk``), outputs in buffers of length ``chunk``."""
    one = _transition(spec, target.log_density)
    chains = carry["position"].shape[0]
    d = target.origin.shape[0]  # θ has every coordinate; the positions ζ only the sampled subspace's
    dtype = carry["position"].dtype
    buffers = (
        jnp.zeros((chunk, chains, d), dtype),
        jnp.zeros((chunk, chains), dtype),
        {
            "acceptance_rate": jnp.zeros((chunk, chains), dtype),
            "divergent": jnp.zeros((chunk, chains), jnp.uint8),
            "integration_steps": jnp.zeros((chunk, chains), jnp.int64 if dtype == jnp.float64 else jnp.int32),
            "step_size": jnp.zeros((chunk, chains), dtype),
        },
    )

    def body(j, state):
        c, (theta_buf, lp_buf, stats_buf) = state
        i = start + j
        keys = jax.random.split(jax.random.fold_in(key, i), chains)
        c, (z, ld, acc, div, steps, eps) = jax.vmap(one, in_axes=(0, 0, None))(keys, c, i < warmup)
        theta, lp = _record(target, z, ld)
        theta_buf = theta_buf.at[j].set(theta)
        lp_buf = lp_buf.at[j].set(lp)
        stats_buf = {
            "acceptance_rate": stats_buf["acceptance_rate"].at[j].set(acc),
            "divergent": stats_buf["divergent"].at[j].set(div.astype(jnp.uint8)),
            "integration_steps": stats_buf["integration_steps"]
            .at[j]
            .set(steps.astype(stats_buf["integration_steps"].dtype)),
            "step_size": stats_buf["step_size"].at[j].set(eps),
        }
        return c, (theta_buf, lp_buf, stats_buf)

    return jax.lax.fori_loop(0, n, body, (carry, buffers))


_WINDOW_KEY = 2**32 - 1  # fold_in datum of the window adaptation's key (the steps use their index)


@eqx.filter_jit
def _window_warmup(target, spec, carry, key, warmup):
    """BlackJAX's window adaptation of every chain from its start (``adapt_mass_matrix=True``):
    the carry after ``warmup`` steps and the warm-up block (θ, log p(θ), statistics)."""
    blackjax = _blackjax()
    kind, max_doublings, trajectory_length, _, acceptance = spec
    logdensity = target.log_density
    steps = math.ceil(trajectory_length / _INITIAL_STEP_SIZE)
    algorithm, extra = (
        (blackjax.nuts, {"max_num_doublings": max_doublings})
        if kind == "nuts"
        else (blackjax.hmc, {"num_integration_steps": steps})
    )

    def one(k, z, imm):
        adaptation = blackjax.window_adaptation(
            algorithm,
            logdensity,
            is_mass_matrix_diagonal=False,
            initial_inverse_mass_matrix=imm,
            initial_step_size=_INITIAL_STEP_SIZE,
            target_acceptance_rate=acceptance,
            **extra,
        )
        # BlackJAX's RunFn protocol leaves out num_steps, which window_adaptation's run takes
        (state, parameters), info = adaptation.run(k, z, num_steps=warmup)  # pyright: ignore[reportCallIssue]
        return state, parameters["step_size"], parameters["inverse_mass_matrix"], info

    chains = carry["position"].shape[0]
    keys = jax.random.split(jax.random.fold_in(key, _WINDOW_KEY), chains)
    state, step_size, imm, info = jax.vmap(one)(keys, carry["position"], carry["inverse_mass_matrix"])
    log_eps = jnp.log(step_size)
    carry = {
        **carry,
        "position": state.position,
        "logdensity": state.logdensity,
        "logdensity_grad": state.logdensity_grad,
        "log_step_size": log_eps,
        "log_step_size_avg": log_eps,
        "inverse_mass_matrix": imm,
    }
    z = jnp.swapaxes(info.state.position, 0, 1)
    theta, lp = _record(target, z, jnp.swapaxes(info.state.logdensity, 0, 1))
    rate = jnp.swapaxes(info.info.acceptance_rate, 0, 1)
    stats = {
        "acceptance_rate": jnp.where(jnp.isfinite(rate), rate, 0.0),
        "divergent": jnp.swapaxes(info.info.is_divergent, 0, 1).astype(jnp.uint8),
        "integration_steps": jnp.swapaxes(info.info.num_integration_steps, 0, 1).astype(jnp.int64),
        "step_size": jnp.swapaxes(
            jnp.exp(info.adaptation_state.log_step_size)
            if hasattr(info.adaptation_state, "log_step_size")
            else jnp.broadcast_to(step_size[:, None], rate.T.shape),
            0,
            1,
        ),
    }
    return carry, (theta, lp, stats)
