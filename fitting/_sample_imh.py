"""Independence Metropolis–Hastings from the Laplace approximation for :func:`fitting.sample`: one log-density per
step, no gradient, all chains in one program.

Every step of every chain proposes a fresh draw of a fixed proposal q — a multivariate Student-t with ``dof``
degrees of freedom centred on the Laplace maximum ζ* with scale matrix ``scale²·Σ_ζ``
(:func:`fitting._posterior.laplace`, in the coordinates ζ of the determined subspace, :mod:`fitting._posterior`) —
independently of where the chain is, and accepts it with the probability

    α = min(1, w(ζ') / w(ζ)),   w = p / q,

the ratio of the importance weights of the proposal and of the current state (Tierney 1994, "Markov chains for
exploring posterior distributions", Ann. Statist. 22, §2.3.1). The chain's stationary distribution is the
posterior p whatever q is, as long as q is positive wherever p is; it is uniformly ergodic when w is bounded
(Mengersen & Tweedie 1996), which the t proposal's polynomial tails give for posteriors with Gaussian or lighter
tails. How fast it mixes depends on how well q matches p: on the near-Gaussian posterior of an adequate fit with
many pixels the Laplace approximation is close and most proposals are accepted — each step is then nearly an
independent draw at the price of one log-density, where a NUTS transition costs several gradients. Where the
Laplace approximation is poor (a model that does not describe its data: the Gauss–Newton covariance leaves out the
residuals' curvature), the weights vary over orders of magnitude, the chains stick, and R̂ and the ESS say so
(``SampleResult.status``): sample that posterior with NUTS instead.

No adaptation and so no warm-up: the chains start from independent draws of the Laplace approximation (as NUTS's
do), already near the stationary distribution when q is good, and the status checks that they mixed. The proposal
(its centre and square-root scale matrix) is part of the carry the checkpoint stores, so a resumed run proposes
exactly what the uninterrupted run proposes.

Randomness: step i of all chains uses ``jax.random.split(fold_in(PRNGKey(seed), i), chains)``, as the gradient
samplers' steps do (:mod:`fitting._sample_blackjax`): a step's draws depend on its index only.

Verified in tests/test_samplers.py: the exact linear-Gaussian posterior (mean and covariance within Monte-Carlo
errors), bit-identical resume after an interruption, the acceptance rate of a proposal equal to the posterior, and
the status on a posterior the Laplace approximation misses.
"""

import dataclasses
import functools
import math
import time
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import InvalidInputError
from brdfscale.checks import real
from brdfscale.choices import SAMPLE
from brdfscale.show import progress_bar

from ._checkpoint import resumed_blocks
from ._posterior import covariance_root, initial_positions, laplace
from ._sampler import AbstractSampler, out_of_time, paced


__all__ = ["IMH"]

_STATS = {"acceptance_rate": "f8"}


@dataclasses.dataclass(frozen=True)
class IMH(AbstractSampler):
    """Independence Metropolis–Hastings with the Laplace approximation as proposal (module docstring): ``chains``
    chains vmapped, one log-density evaluation per step and chain, no gradient and no warm-up.

    Args:
        dof: the Student-t proposal's degrees of freedom (default 10; ``math.inf``: a Gaussian proposal, whose light
            tails make the sampler slow to leave a posterior's tail the Laplace approximation underestimates).
        scale: the proposal's scale matrix in units of the Laplace covariance (default 1.0; > 1 widens it).

    Fast where the Laplace approximation is close to the posterior (an adequate fit of many pixels: the
    27-parameter anisotropic model's posterior in docs/fitting.md, "Speed of the default fit"); where it is not,
    the chains stick and the status says not converged — NUTS (the default) adapts to any smooth posterior.
    """

    dof: float = 10.0
    scale: float = 1.0
    name = "imh"
    stats: ClassVar[dict] = _STATS
    default_steps = SAMPLE.steps_for("imh")

    def __post_init__(self):
        if not (isinstance(self.dof, float) and self.dof == math.inf):  # ∞: the Gaussian proposal
            object.__setattr__(self, "dof", real(self.dof, "dof (or math.inf: a Gaussian)", minimum=0.0, strict=True))
        object.__setattr__(self, "scale", real(self.scale, "scale", minimum=0.0, strict=True))

    def settings(self, d: int) -> dict:
        # JSON and HDF5 attributes hold no infinity: a Gaussian proposal is recorded as dof None
        return {"name": self.name, "dof": None if math.isinf(self.dof) else self.dof, "scale": self.scale}

    def trajectories(self, d: int, chains: int) -> int:
        return chains

    def check_batched(self) -> None:
        raise InvalidInputError(
            "sample_many samples with NUTS or HMC only; use fitting.sample(problem, fit, sampler='imh') per material."
        )

    def burn_in(self, chain, warmup):
        """None: the chains start from draws of the Laplace approximation and nothing adapts (module docstring)."""
        return 0, warmup

    def log_weights(self, target, fit, *, draws: int, seed: int, batch: int) -> np.ndarray:
        """``log w = log p − log q`` (up to one constant) at ``draws`` independent draws of this sampler's proposal
        q: the importance weights whose Pareto k̂ (:func:`fitting.pareto_k`) says whether q covers the posterior
        (:class:`fitting.Auto`). Drawn from NumPy's generator of ``(seed, 1)``, apart from the chains' streams;
        weighed ``batch`` at a time (the chains' count) by the computation that weighs the chains' starts, in one
        compiled program that maps over the batches (one dispatch; memory for one batch at a time)."""
        mode, cov = laplace(target, fit)
        root = self.scale * covariance_root(cov)
        rng = np.random.default_rng([seed, 1])
        xi = rng.standard_normal((draws, mode.size))
        if not math.isinf(self.dof):
            xi = xi / np.sqrt(rng.chisquare(self.dof, (draws, 1)) / self.dof)
        z = mode + xi @ root.T
        z = np.concatenate([z, np.broadcast_to(mode, (-draws % batch, mode.size))])  # whole batches
        weights = _batched_log_weights(
            target, jnp.asarray(z.reshape(-1, batch, mode.size)), jnp.asarray(mode), jnp.asarray(root), self.dof
        )
        return np.asarray(weights).reshape(-1)[:draws]

    def run(self, target, fit, *, chains, steps, seed, store, resumed, progress, chunk, deadline=None):
        """The chain (steps, chains, d) in θ, log_prob, the acceptance probabilities and the proposal's record;
        resumed from ``resumed`` where it holds steps, each chunk appended to ``store``; ended early where
        :func:`fitting._sampler.out_of_time` says so for ``deadline``."""
        blocks, carry = resumed_blocks(resumed, steps)
        if carry is None:
            mode, cov = laplace(target, fit)
            root = covariance_root(cov)
            z0 = initial_positions(mode, root, chains, np.random.default_rng(seed))
            root = self.scale * root
            carry = _host(_initial_carry(target, jnp.asarray(z0), jnp.asarray(mode), jnp.asarray(root), self.dof))
        done = blocks[0][0].shape[0] if blocks else 0
        timing = {"warmup_s": 0.0, "sampling_s": 0.0}
        key = jax.random.PRNGKey(seed)
        advance = functools.partial(_advance, target, self.dof)
        with progress_bar(enabled=progress, total=steps, initial=min(done, steps), desc=self.name, unit="step") as bar:
            first = done
            while done < steps and not out_of_time(deadline, done):
                n = paced(min(chunk, steps - done), deadline, timing["sampling_s"], done - first, done)
                started = time.perf_counter()
                carry, out = advance(carry, np.int64(done), np.int64(n), key, chunk)
                carry = _host(carry)
                block = jax.tree_util.tree_map(lambda a, n=n: np.asarray(a)[:n], out)
                timing["sampling_s"] += time.perf_counter() - started
                if store is not None:
                    store.append(*block, carry)
                blocks.append(block)
                done += n
                bar.update(n)
        chain = np.concatenate([b[0] for b in blocks])
        log_prob = np.concatenate([b[1] for b in blocks])
        stats = {k: np.concatenate([b[2][k] for b in blocks]) for k in _STATS}
        record = {
            "kind": (
                "none: independence Metropolis–Hastings adapts nothing; proposal "
                + ("Gaussian" if math.isinf(self.dof) else f"Student-t ({self.dof:g} degrees of freedom)")
                + f", the Laplace approximation's covariance × {self.scale:g}²"
            ),
            "steps": 0,
            "acceptance_rate": float(np.mean(stats["acceptance_rate"])) if steps else None,
        }
        return chain, log_prob, stats, record, timing


def _host(carry) -> dict:
    """The carry as float64 NumPy arrays (its dtypes never change: one compiled program serves every chunk)."""
    return {k: np.asarray(v, dtype=np.float64) for k, v in carry.items()}


def _log_q(xi, dof):
    """log q of a proposal at standardised coordinates ξ (ζ = centre + root·ξ), up to a constant the acceptance
    ratio cancels: −(ν + m)/2·log(1 + ξᵀξ/ν) for the Student-t, −ξᵀξ/2 for the Gaussian (ν = ∞)."""
    r2 = jnp.sum(xi * xi, axis=-1)
    if math.isinf(dof):
        return -0.5 * r2
    return -0.5 * (dof + xi.shape[-1]) * jnp.log1p(r2 / dof)


@eqx.filter_jit
def _batched_log_weights(target, z, mode, root, dof):
    """:func:`_initial_carry`'s log weights of every batch ``z[i]`` (batches, batch, m), one batch at a time."""
    return jax.lax.map(lambda batch: _initial_carry(target, batch, mode, root, dof)["log_weight"], z)


@eqx.filter_jit
def _initial_carry(target, z0, mode, root, dof):
    """The chains' starts, their log-densities and log importance weights, and the proposal (centre, root) per chain."""
    xi = jnp.linalg.solve(root, (z0 - mode).T).T
    value = jax.vmap(target.log_density)(z0)
    weight = jnp.where(jnp.isfinite(value), value - _log_q(xi, dof), -jnp.inf)
    chains = z0.shape[0]
    return {
        "position": z0,
        "logdensity": value,
        "log_weight": weight,
        "centre": jnp.broadcast_to(mode, (chains,) + mode.shape),
        "root": jnp.broadcast_to(root, (chains,) + root.shape),
    }


@eqx.filter_jit
def _advance(target, dof, carry, start, n, key, chunk):
    """Steps ``start … start + n − 1`` of every chain (``n ≤ chunk``), outputs in buffers of length ``chunk``."""
    chains, m = carry["position"].shape
    d = target.origin.shape[0]
    dtype = carry["position"].dtype

    def one(k, c):
        k_xi, k_g, k_u = jax.random.split(k, 3)
        xi = jax.random.normal(k_xi, (m,), dtype)
        if not math.isinf(dof):  # a Student-t draw: a normal over the root of a χ²_ν/ν
            xi = xi * jax.lax.rsqrt(2.0 * jax.random.gamma(k_g, dof / 2, (), dtype) / dof)
        proposal = c["centre"] + c["root"] @ xi
        value = target.log_density(proposal)
        weight = jnp.where(jnp.isfinite(value), value - _log_q(xi, dof), -jnp.inf)
        log_alpha = jnp.minimum(0.0, weight - c["log_weight"])
        log_alpha = jnp.where(jnp.isnan(log_alpha), -jnp.inf, log_alpha)
        accept = jnp.log(jax.random.uniform(k_u, (), dtype)) < log_alpha
        new = {
            **c,
            "position": jnp.where(accept, proposal, c["position"]),
            "logdensity": jnp.where(accept, value, c["logdensity"]),
            "log_weight": jnp.where(accept, weight, c["log_weight"]),
        }
        return new, (new["position"], new["logdensity"], jnp.exp(log_alpha))

    buffers = (
        jnp.zeros((chunk, chains, d), dtype),
        jnp.zeros((chunk, chains), dtype),
        jnp.zeros((chunk, chains), dtype),
    )

    def body(j, state):
        c, (theta_buf, lp_buf, acc_buf) = state
        keys = jax.random.split(jax.random.fold_in(key, start + j), chains)
        c, (z, ld, acc) = jax.vmap(one)(keys, c)
        theta_buf = theta_buf.at[j].set(target.theta(z))
        lp_buf = lp_buf.at[j].set(target.log_prob_theta(z, ld))
        return c, (theta_buf, lp_buf, acc_buf.at[j].set(acc))

    carry, (theta, lp, acc) = jax.lax.fori_loop(0, n, body, (carry, buffers))
    return carry, (theta, lp, {"acceptance_rate": acc})
