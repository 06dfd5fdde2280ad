"""emcee for :func:`fitting.sample`: independent affine-invariant ensembles, one vectorised log-density.

``chains`` ensembles of ``walkers`` walkers each run side by side in one
``emcee.EnsembleSampler`` whose move, :class:`_IndependentEnsembles`, applies emcee's own
proposal (the stretch move, or differential evolution + snooker) within each ensemble only:
a walker's complementary set is drawn from its own ensemble, so the ensembles exchange no
information and are independent chains of ensembles (their walkers together are the
trajectories ArviZ sees as chains, as ``arviz.from_emcee`` does). Every half-step evaluates
the proposals of all ensembles in one call of one compiled ``jax.vmap`` of
:meth:`fitting._posterior.Target.log_density` (two calls per step, whatever the number of ensembles).

The walkers move in the sampling coordinates ζ of the determined subspace
(:mod:`fitting._posterior`); each ensemble starts in a ball of 0.1 × the Laplace covariance
about its own centre, a draw of the Laplace approximation (the first ensemble's centre is the
maximum itself): over-dispersed between ensembles, so R̂ compares ensembles that started apart.
"""

import dataclasses
import time
from typing import cast, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import InvalidInputError
from brdfscale.checks import integer
from brdfscale.choices import SAMPLE
from brdfscale.show import progress_bar

from . import _diagnostics as diag
from ._posterior import covariance_root, initial_positions, laplace, log_jacobian_np, theta_of_z_np
from ._sampler import AbstractSampler, out_of_time, paced


__all__ = ["Emcee"]

_MOVES = ("stretch", "de")


def _emcee():
    """emcee, imported on first use (importing brdfscale.fitting stays light)."""
    import emcee

    return emcee


@eqx.filter_jit
def _batched_log_density(zs, target):
    return jax.vmap(target.log_density)(zs)


@dataclasses.dataclass(frozen=True)
class Emcee(AbstractSampler):
    """emcee's affine-invariant ensemble sampler, ``chains`` independent ensembles (module docstring).

    Args:
        walkers: walkers per ensemble (default ``max(32, 4·dim)``; at least 2·dim, made even;
            dim the sampled subspace's dimension, the coordinates less the undetermined ones).
        moves: ``"stretch"`` (default) or ``"de"`` (differential evolution 0.8 + snooker 0.2).

    There is no adaptive warm-up: the chain's first steps are discarded as burn-in after the
    run, 2 τ_max (emcee's integrated autocorrelation time), at most half the chain.
    """

    walkers: int | None = None
    moves: str = "stretch"
    name = "emcee"
    default_steps = SAMPLE.steps_for("emcee")  # τ is tens of steps: long chains for ESS ≥ 400

    def __post_init__(self):
        if self.walkers is not None:
            object.__setattr__(self, "walkers", integer(self.walkers, "walkers", 2))
        if not isinstance(self.moves, str) or self.moves not in _MOVES:
            raise InvalidInputError(f"moves must be one of {list(_MOVES)}; got {self.moves!r}.")

    def walkers_for(self, d: int) -> int:
        """Walkers per ensemble for ``d`` coordinates (checked against 2·d, made even)."""
        walkers = max(32, 4 * d) if self.walkers is None else integer(self.walkers, "walkers", 2 * d)
        return walkers + walkers % 2

    def settings(self, d: int) -> dict:
        """What the checkpoint records of this sampler."""
        return {"name": self.name, "walkers": self.walkers_for(d), "moves": self.moves}

    def trajectories(self, d: int, chains: int) -> int:
        return chains * self.walkers_for(d)

    stats: ClassVar[dict] = {}  # no per-step statistics beyond the chain

    @classmethod
    def from_name(cls, walkers=None, moves=None) -> "Emcee":
        """``sample(..., sampler="emcee", walkers=, moves=)``: the sampler with those settings."""
        return cls(walkers=walkers, moves="stretch" if moves is None else moves)

    def refuse_walkers(self) -> InvalidInputError:
        return InvalidInputError(
            "walkers= and moves= with a sampler object: give them in fitting.Emcee(walkers=…, moves=…)."
        )

    def check_batched(self) -> None:
        raise InvalidInputError(
            "sample_many samples with NUTS or HMC only: emcee's ensembles step on the host "
            "(one vectorised log-density call per half-step, NumPy in between) and do not "
            "vectorise across materials; use fitting.sample(problem, fit, sampler='emcee') per "
            "material."
        )

    def burn_in(self, chain, warmup):
        """2 τ_max (emcee's integrated autocorrelation time of the whole chain), at most half
        the chain; half the chain where τ is not finite (a coordinate no walker moved in:
        short chains, stuck ensembles — τ taken as ∞)."""
        n_steps = chain.shape[0]
        tau_all = diag.integrated_time(chain)
        burn = int(min(np.ceil(2 * np.max(tau_all)), n_steps // 2)) if np.all(np.isfinite(tau_all)) else n_steps // 2
        return burn, {"kind": "burn-in: the first 2 τ_max steps (at most half the chain), discarded", "steps": burn}

    def run(self, target, fit, *, chains, steps, seed, store, resumed, progress, chunk, deadline=None):
        """The chain (steps, W, d) in θ and log_prob (steps, W); resumed from ``resumed`` (a
        :class:`~fitting._checkpoint.Stored`) where it holds steps, every chunk appended to ``store``."""
        emcee = _emcee()
        m = target.dimension  # the sampled (determined) subspace
        walkers = self.walkers_for(m)
        n = chains * walkers
        lo, hi = np.asarray(target.problem.lower), np.asarray(target.problem.upper)
        subspace = target.record()

        def logp(zetas):
            out = np.asarray(_batched_log_density(jnp.asarray(zetas), target))
            return np.where(np.isfinite(out), out, -np.inf)

        moves = (
            [(_IndependentEnsembles(emcee.moves.StretchMove(), chains, walkers), 1.0)]
            if self.moves == "stretch"
            else [
                (_IndependentEnsembles(emcee.moves.DEMove(), chains, walkers), 0.8),
                (_IndependentEnsembles(emcee.moves.DESnookerMove(), chains, walkers), 0.2),
            ]
        )
        sampler = emcee.EnsembleSampler(n, m, logp, vectorize=True, moves=moves)
        chains_out, log_probs = [], []
        if resumed is not None and resumed.steps > 0:
            chains_out, log_probs = [resumed.chain[:steps]], [resumed.log_prob[:steps]]
            s = resumed.state
            random_state = (
                "MT19937",
                s["rng_keys"],
                int(s["rng_pos"]),
                int(s["rng_has_gauss"]),
                float(s["rng_cached_gaussian"]),
            )
            state = emcee.State(np.array(s["position"]), log_prob=np.array(s["log_density"]), random_state=random_state)
        else:
            rng = np.random.default_rng(seed)
            mode, cov = laplace(target, fit)
            root = covariance_root(cov)
            centres = np.vstack([mode, initial_positions(mode, root, chains - 1, rng)])
            p0 = np.concatenate([initial_positions(c, root, walkers, rng, scale=0.1) for c in centres])
            sampler.random_state = np.random.RandomState(seed).get_state()
            state = emcee.State(p0, log_prob=logp(p0), random_state=sampler.random_state)
        done = sum(c.shape[0] for c in chains_out)
        first = done
        timing = {"run_s": 0.0, "steps": 0}  # this call's computing (checkpoint writes excluded)
        with progress_bar(enabled=progress, total=steps, initial=min(done, steps), desc="emcee", unit="step") as bar:
            while done < steps and not out_of_time(deadline, done):
                k = paced(min(chunk, steps - done), deadline, timing["run_s"], done - first, done)
                started = time.perf_counter()
                block, block_lp = np.empty((k, n, m)), np.empty((k, n))
                for j, new in enumerate(sampler.sample(state, iterations=k, store=False)):
                    block[j], block_lp[j] = new.coords, new.log_prob
                    bar.update(1)
                state = new  # k ≥ 1 steps were taken
                state.random_state = sampler.random_state
                z = subspace["origin"] + block @ subspace["basis"].T
                theta = theta_of_z_np(z, lo, hi)
                lp_theta = block_lp - log_jacobian_np(z, lo, hi)
                timing["run_s"] += time.perf_counter() - started
                if store is not None:
                    # emcee's random_state is RandomState.get_state(), legacy by default: the tuple (name, keys,
                    # pos, has_gauss, cached_gaussian); NumPy's stubs give that call the dict of legacy=False
                    rs = cast(tuple, state.random_state)
                    store.append(
                        theta,
                        lp_theta,
                        {},
                        {
                            "position": state.coords,
                            "log_density": state.log_prob,
                            "rng_keys": rs[1],
                            "rng_pos": np.int64(rs[2]),
                            "rng_has_gauss": np.int64(rs[3]),
                            "rng_cached_gaussian": np.float64(rs[4]),
                        },
                    )
                chains_out.append(theta)
                log_probs.append(lp_theta)
                done += k
        timing["steps"] = done - first  # fewer than asked where the deadline ended the run
        return np.concatenate(chains_out), np.concatenate(log_probs), {}, None, timing


class _IndependentEnsembles:
    """An emcee move that applies ``inner`` (a red–blue move of emcee) within each of
    ``chains`` blocks of ``walkers`` consecutive walkers: the ensembles stay independent,
    and each half-step evaluates all of their proposals in one vectorised call."""

    def __init__(self, inner, chains: int, walkers: int):
        self.inner, self.chains, self.walkers = inner, chains, walkers
        self._base = _emcee().moves.Move()

    def propose(self, model, state):
        emcee, inner, w = _emcee(), self.inner, self.walkers
        n = state.coords.shape[0]
        inner.setup(state.coords[:w])
        accepted = np.zeros(n, dtype=bool)
        inds = np.tile(np.arange(w) % inner.nsplits, self.chains)
        if inner.randomize_split:
            for e in range(self.chains):
                model.random.shuffle(inds[e * w : (e + 1) * w])
        for split in range(inner.nsplits):
            subset = inds == split
            proposals, factors = [], []
            for e in range(self.chains):
                coords, labels = state.coords[e * w : (e + 1) * w], inds[e * w : (e + 1) * w]
                sets = [coords[labels == j] for j in range(inner.nsplits)]
                q, f = inner.get_proposal(sets[split], sets[:split] + sets[split + 1 :], model.random)
                proposals.append(q)
                factors.append(f)
            q, f = np.concatenate(proposals), np.concatenate(factors)
            new_log_probs, new_blobs = model.compute_log_prob_fn(q)
            accept = f + new_log_probs - state.log_prob[subset] > np.log(model.random.rand(q.shape[0]))
            accepted[np.flatnonzero(subset)[accept]] = True
            state = self._base.update(state, emcee.State(q, log_prob=new_log_probs, blobs=new_blobs), accepted, subset)
        return state, accepted
