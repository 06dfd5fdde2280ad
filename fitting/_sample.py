"""Posterior sampling: emcee, NUTS, HMC or IMH on one posterior, independent chains, resumable checkpoints, diagnostics.

Every sampler draws from the same posterior, :func:`fitting.log_posterior` — ``−½χ²(θ)``
uniform on the model's prior box, in the model's unconstrained coordinates θ — through the
same smooth, unbounded coordinates z, ``θ = lo + (hi − lo)·σ(z)``, Jacobian included
(:mod:`fitting._posterior` states it), preconditioned by the fit's Laplace approximation in z:

* :class:`fitting.Emcee` — emcee's affine-invariant ensembles (stretch, or differential
  evolution), ``chains`` independent ensembles advanced together, one vectorised log-density
  call per half-step (:mod:`fitting._sample_emcee`);
* :class:`fitting.NUTS`, :class:`fitting.HMC` — BlackJAX's kernels with the Laplace covariance
  as inverse mass matrix, step size tuned in a recorded warm-up, ``chains`` chains vmapped in
  one compiled program (:mod:`fitting._sample_blackjax`);
* :class:`fitting.IMH` — independence Metropolis–Hastings with the Laplace approximation (a Student-t about it) as
  the proposal of every step: one log-density and no gradient per step, ``chains`` chains vmapped in one compiled
  program; fast where that approximation is close to the posterior, stuck (and said so by the status) where it is
  not (:mod:`fitting._sample_imh`).

Directions the data do not determine (the fit's ``undetermined`` combinations) are not
sampled: every sampler moves in the determined subspace through the optimum, those
combinations held at the fit's values (:mod:`fitting._posterior` says why and what it costs),
and the result says so (``SampleResult.undetermined``, ``held``, ``prior``); the convergence
status is decided on the quantities the fit determines.

Checkpoints (:mod:`fitting._checkpoint`): with ``checkpoint=PATH`` every ``chunk`` steps
are appended to an HDF5 file together with the sampler's state and the chunk's SHA-256; an
interrupted run (Ctrl-C, crash, kill) resumes from the last completed chunk and yields the very
same chain, bit for bit, for every sampler. Every chunk is verified before it is resumed (or
read as a finished chain): a damaged one — changed bytes, NaN — is refused, naming the chunk;
:func:`fitting.rewind_checkpoint` keeps the chunks before it, from which the run continues to
the undamaged run's chain (tests/test_checkpoint_integrity.py).

Diagnostics (:mod:`fitting._diagnostics`): ArviZ's rank-normalised split R̂, bulk and tail
ESS and MCSE of every coordinate and quantity (``SampleResult.summary()``), and emcee's
integrated autocorrelation time τ with ``ESS = trajectories · steps / τ`` (the report's
figures since the first version); ``SampleResult.status`` is ``"converged"`` only when every
determined quantity has R̂ ≤ 1.01 and bulk ESS ≥ 400 and no post-warm-up transition
diverged — otherwise it names what failed, never silently.
"""

import contextlib
import dataclasses
import functools
import hashlib
import os
import time

import jax
import numpy as np

from brdfscale import InvalidInputError
from brdfscale.checks import flag, integer, real
from brdfscale.choices import SAMPLE
from brdfscale.files import exclusive
from brdfscale.show import progress_mode, Shown, Table

from . import _diagnostics as diag
from ._checkpoint import Checkpoint, recorded_signature
from ._derived import quantities_at
from ._posterior import (
    COORDINATES,
    log_posterior,
    PRIOR_TEXT,
    target,
    undetermined_directions,
)
from ._problem import check_fit, Problem
from ._result import FitResult
from ._sample_auto import Auto
from ._sample_blackjax import HMC, NUTS
from ._sample_emcee import Emcee
from ._sample_imh import IMH
from ._sampler import AbstractChoice


__all__ = ["HMC", "IMH", "NUTS", "SAMPLERS", "Auto", "Emcee", "SampleResult", "log_posterior", "sample"]

SAMPLERS = {"emcee": Emcee, "nuts": NUTS, "hmc": HMC, "imh": IMH, "auto": Auto}
"""The samplers by name: ``sample(..., sampler="nuts")`` is ``sampler=fitting.NUTS()``."""


@dataclasses.dataclass(repr=False)
class SampleResult(Shown):
    """The chain and its diagnostics.

    Layout: ``chain`` (steps, W, d) holds θ of every trajectory after every step — W = the
    walkers of all ``chains`` emcee ensembles (ensemble-major: walker w belongs to ensemble
    ``w // (W / chains)``), or one trajectory per NUTS/HMC chain; warm-up (burn-in) steps
    included. ``log_prob`` (steps, W) is log p(θ | data) = −½χ²(θ) + const (the θ-density, no
    Jacobian), ``stats``
    per-step sampler statistics (NUTS/HMC: ``acceptance_rate``, ``divergent``,
    ``integration_steps``, ``step_size``), ``quantities`` the model's physical quantities
    (name → (steps, W)). The first ``burn`` steps are discarded: NUTS/HMC's warm-up, or for
    emcee 2 τ_max (at most half the chain). ``samples`` is the flattened chain after them
    (n, d); ``draws`` the same as (W, steps − burn, d), one row per trajectory;
    :meth:`by_chain` puts any per-trajectory array in ArviZ's (chain, draw) layout, one chain
    per independent chain (an emcee ensemble's ``walkers`` trajectories one after another).
    ``undetermined`` are the fit's undetermined combinations, ``held`` their values, at which
    the chain holds them (it samples the determined subspace; ``prior`` says it in words).

    ``timing``: seconds this call spent computing steps (checkpoint writes and steps resumed
    from a checkpoint not counted): ``warmup_s`` — NUTS/HMC's warm-up, or for emcee the
    burn-in's share of its run (emcee has no warm-up phase; its burn-in is found afterwards);
    ``sampling_s`` — the rest. The first call of a problem shape includes compilation in them.

    ``chosen_by``: where a rule chose the sampler (:class:`fitting.Auto`), its record — ``chose`` (``sampler``,
    the one that ran), the ``pareto_k`` of the proposal's importance weights (None: infinite), the ``limit`` it was
    held to and the ``draws`` weighed (a resumed run's: the record of the run that wrote the checkpoint); None where
    the sampler was given. ``timing["choice_s"]``: the seconds the choice took in this call.

    ``stopped``: where the run ended at :func:`fitting.sample`'s ``time_limit`` before the steps it was asked for,
    ``{"time_limit_s", "steps", "steps_asked"}`` (the steps held, warm-up included, and those a complete run holds);
    the status then names it first. None: the run is complete.

    ``tau``, ``ess``, ``tau_reliable``: emcee's integrated autocorrelation time per
    coordinate after the burn-in, ``ESS = W·(steps − burn)/τ``, and whether the chain is
    ≥ 50 τ long. :meth:`summary` gives ArviZ's figures (R̂, bulk/tail ESS, MCSE),
    :attr:`status` the verdict.
    """

    names: tuple[str, ...]
    chain: np.ndarray
    log_prob: np.ndarray
    burn: int
    tau: np.ndarray
    ess: np.ndarray
    tau_reliable: bool
    acceptance: float
    sampler: str = "emcee"
    chains: int = 1
    settings: dict = dataclasses.field(default_factory=dict)
    warmup: dict | None = None
    stats: dict = dataclasses.field(default_factory=dict)
    quantities: dict | None = None
    determined: tuple[str, ...] | None = None
    undetermined: list = dataclasses.field(default_factory=list)
    held: list = dataclasses.field(default_factory=list)
    prior: str = PRIOR_TEXT
    coordinates: str = COORDINATES
    timing: dict | None = None
    chosen_by: dict | None = None
    stopped: dict | None = None

    @property
    def samples(self) -> np.ndarray:
        return self.chain[self.burn :].reshape(-1, self.chain.shape[-1])

    @property
    def draws(self) -> np.ndarray:
        """θ after the burn-in as (trajectory, draw, d): one row per trajectory (NUTS/HMC chain or emcee walker)."""
        return np.swapaxes(self.chain[self.burn :], 0, 1)

    @property
    def walkers(self) -> int:
        """Trajectories per independent chain: the walkers of each emcee ensemble as given
        (``Emcee(walkers=…)``, or its default), 1 for NUTS/HMC."""
        return self.chain.shape[1] // max(self.chains, 1)

    def by_chain(self, values) -> np.ndarray:
        """``values`` (steps, W, …) — per step and trajectory — in ArviZ's (chain, draw, …)
        layout with one chain per independent chain: a NUTS/HMC chain's steps, or an emcee
        ensemble's walkers' trajectories one after another (walker-major: its draws are
        ``walkers × steps``). R̂ then compares independent chains — ensembles that started
        apart and never exchange information — not the walkers of one ensemble, which move
        together; each walker's autocorrelation stays whole within its run of draws."""
        values = np.asarray(values)
        steps, W = values.shape[:2]
        k = max(self.chains, 1)
        per = values.reshape(steps, k, W // k, *values.shape[2:])
        return np.moveaxis(per, 0, 2).reshape(k, (W // k) * steps, *values.shape[2:])

    @functools.cached_property
    def _summary(self) -> dict:
        rows = {}
        for i, name in enumerate(self.names):
            rows[name] = diag.summary_row(self.by_chain(self.chain[self.burn :, :, i]))
        for name, values in (self.quantities or {}).items():
            if name not in rows:
                rows[name] = diag.summary_row(self.by_chain(values[self.burn :]))
        return rows

    def summary(self) -> dict:
        """ArviZ's summary figures (``arviz.summary(..., kind="all")`` without the HDI) of every
        coordinate θ and quantity after the burn-in: name → ``mean``, ``sd``, ``mcse_mean``,
        ``mcse_sd``, ``ess_bulk``, ``ess_tail``, ``r_hat`` (computed by
        :mod:`fitting._diagnostics`, equal to ArviZ's; no ArviZ needed)."""
        return {name: dict(row) for name, row in self._summary.items()}

    def _gated(self) -> list[str]:
        """The names whose diagnostics decide the status: the determined quantities that vary
        (fixed parameters are constant), else every coordinate θ."""
        if self.quantities:
            names = [n for n in self.quantities if self.determined is None or n in self.determined]
        else:
            names = list(self.names)
        return [n for n in names if self._summary[n]["sd"] != 0]

    @property
    def divergent(self) -> int:
        """Divergent transitions after the warm-up (NUTS/HMC; 0 for emcee)."""
        d = self.stats.get("divergent")
        return 0 if d is None else int(np.sum(d[self.burn :]))

    def problems(self) -> list[str]:
        """What keeps the run from counting as converged (empty when it does): the time limit reached before
        the steps asked for, R̂ above 1.01 or bulk ESS below 400 on a determined quantity, divergent transitions."""
        out = []
        if self.stopped is not None:
            s = self.stopped
            out.append(
                f"time limit of {s['time_limit_s']:g} s reached after {s['steps']} of {s['steps_asked']} steps "
                "(run again with the same checkpoint to continue)"
            )
        rows = self._summary
        gated = self._gated()
        high = [(n, rows[n]["r_hat"]) for n in gated if not rows[n]["r_hat"] <= diag.R_HAT_LIMIT]
        low = [(n, rows[n]["ess_bulk"]) for n in gated if not rows[n]["ess_bulk"] >= diag.ESS_BULK_LIMIT]
        if high:
            out.append(f"R̂ > {diag.R_HAT_LIMIT} for " + ", ".join(f"{n} ({_fmt(v)})" for n, v in high))
        if low:
            out.append(f"ESS_bulk < {diag.ESS_BULK_LIMIT} for " + ", ".join(f"{n} ({_fmt(v, 0)})" for n, v in low))
        if self.divergent:
            out.append(f"{self.divergent} divergent transitions after warm-up")
        return out

    @property
    def status(self) -> str:
        """``"converged"``, or ``"not converged: …"`` naming each failed criterion (:meth:`problems`)."""
        problems = self.problems()
        return "converged" if not problems else "not converged: " + "; ".join(problems)

    def _show_items(self):
        n_steps, n_walkers, _ = self.chain.shape
        items = [("sampler", self.sampler), ("chains", self.chains), ("status", self.status)]
        if self.sampler == "emcee":
            items.append(("walkers", self.walkers))
        items += [
            ("steps", n_steps),
            ("burn_in", self.burn),
            ("draws", (n_steps - self.burn) * n_walkers),
            ("acceptance", self.acceptance),
            ("tau_max", float(np.max(self.tau))),
            ("ess_min", float(np.min(self.ess))),
            ("tau_reliable", self.tau_reliable),
            ("chain", self.chain),
        ]
        return items

    def _show_tables(self):
        flat = self.samples
        rows = [
            (name, float(np.mean(flat[:, i])), float(np.std(flat[:, i])), float(self.tau[i]), float(self.ess[i]))
            for i, name in enumerate(self.names)
        ]
        tables = [
            Table(
                "coordinates after burn-in (θ: the model's unconstrained coordinates)",
                ("coordinate", "mean", "std", "τ (steps)", "ESS"),
                rows,
            )
        ]
        summary = self._summary
        tables.append(
            Table(
                f"diagnostics (ArviZ's; status: {self.status})",
                ("name", "mean", "sd", "mcse_mean", "ess_bulk", "ess_tail", "r_hat"),
                [
                    (n, r["mean"], r["sd"], r["mcse_mean"], r["ess_bulk"], r["ess_tail"], r["r_hat"])
                    for n, r in summary.items()
                ],
            )
        )
        return tables

    def plot(self, **options):
        """The chains (trace plots, burn-in marked): :func:`brdfscale.plot.chains` (options as
        there); returns a ``matplotlib.figure.Figure``."""
        from brdfscale._figures import draw

        return draw("chains", self, **options)

    def to_arviz(self):
        """The run as ArviZ data — ``arviz.InferenceData`` (ArviZ 0.x; a DataTree with ArviZ ≥ 1):
        ``posterior`` with one variable per coordinate θ and per determined quantity, named
        by the model (``arviz.summary(data, var_names=["amplitude"])``), one ArviZ chain per
        independent chain (:meth:`by_chain`), ``sample_stats``, the warm-up groups, and the
        sampler's record as attributes (:mod:`fitting._arviz`). ``arviz.summary`` of it gives
        the figures of :meth:`summary`.

        Raises:
            MissingDependencyError: ArviZ is not installed (``pip install "brdfscale[mcmc]"``).
        """
        from ._arviz import to_arviz

        return to_arviz(self)

    def diagnostics(self) -> dict:
        """JSON-able record of the run: sizes, burn-in, τ and ESS (emcee's estimator), ArviZ's
        summary, the status and what decided it, the warm-up, the prior."""
        n_steps, n_walkers, _ = self.chain.shape
        warmup = None
        if self.warmup is not None:
            warmup = {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v) for k, v in self.warmup.items()}
        undetermined_quantities = [
            n for n in (self.quantities or {}) if self.determined is not None and n not in self.determined
        ]
        return {
            "sampler": self.sampler,
            "sampler_settings": self.settings,
            "chains": self.chains,
            "walkers": self.walkers,
            "trajectories": n_walkers,
            "steps": n_steps,
            "burn_in": self.burn,
            "acceptance_fraction": self.acceptance,
            "autocorrelation_time": dict(zip(self.names, self.tau.tolist())),
            "effective_sample_size": dict(zip(self.names, self.ess.tolist())),
            "tau_reliable": self.tau_reliable,
            "tau_note": (
                "chain ≥ 50 τ after burn-in: τ estimate reliable"
                if self.tau_reliable
                else "chain shorter than 50 τ after burn-in: τ (and hence ESS) is a lower-bound estimate; run longer"
            ),
            "status": self.status,
            "problems": self.problems(),
            "criteria": {"r_hat_max": diag.R_HAT_LIMIT, "ess_bulk_min": diag.ESS_BULK_LIMIT, "checked": self._gated()},
            "divergent_transitions": self.divergent,
            "timing_s": self.timing,
            "summary": self.summary(),
            "warmup": warmup,
            "chosen_by": self.chosen_by,
            "stopped": self.stopped,
            "prior": self.prior,
            "coordinates": self.coordinates,
            "undetermined_combinations": [u.get("combination") for u in self.undetermined],
            "held_combinations": self.held,
            "undetermined_quantities": undetermined_quantities,
            "undetermined_note": (
                "the data do not determine these combinations: they are not sampled but held at the fit's values "
                "(the chain samples the determined subspace), so the chain gives them no spread"
                if self.undetermined
                else None
            ),
        }


def _fmt(v, digits: int = 3) -> str:
    return "nan" if not np.isfinite(v) else (f"{v:.{digits}f}" if digits else f"{v:.0f}")


def _digest(tree) -> str:
    """SHA-256 of a pytree: its structure (which holds the static fields — a model's families,
    law, fixed values, quadrature settings) and its arrays (dtypes, shapes and bytes)."""
    h = hashlib.sha256(str(jax.tree_util.tree_structure(tree)).encode())
    for leaf in jax.tree_util.tree_leaves(tree):
        a = np.ascontiguousarray(np.asarray(leaf))
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:32]


def resolve_sampler(sampler, walkers=None, moves=None) -> AbstractChoice:
    """The sampler object of ``sample``'s ``sampler`` (a name of :data:`SAMPLERS`, with
    ``walkers``/``moves`` where it takes them, or an :class:`AbstractChoice` as it is)."""
    if isinstance(sampler, str) and sampler in SAMPLERS:
        return SAMPLERS[sampler].from_name(walkers, moves)
    if not isinstance(sampler, AbstractChoice):
        got = repr(sampler) if isinstance(sampler, str) else type(sampler).__name__
        raise InvalidInputError(
            f"sampler must be one of {sorted(SAMPLERS)} or a sampler object "
            f"(fitting.Emcee, fitting.NUTS, fitting.HMC, fitting.IMH, fitting.Auto); got {got}."
        )
    if walkers is not None or moves is not None:
        raise sampler.refuse_walkers()
    return sampler


def sampled_dimension(problem, fit, what: str) -> int:
    """m = d − k: the dimension of the sampled (determined) subspace; InvalidInputError (``what``
    naming the caller) when the data determine no coordinate at all."""
    d = len(problem.model.names)
    m = d - len(fit.undetermined)
    if m < 1:
        raise InvalidInputError(
            f"{what}: the data determine none of the {d} coordinates (every Fisher "
            "eigen-direction is undetermined); there is nothing to sample."
        )
    return m


def sample(
    problem: Problem,
    fit: FitResult,
    *,
    sampler=SAMPLE.sampler,
    chains: int = SAMPLE.chains,
    steps: int | None = SAMPLE.steps,
    chunk: int = SAMPLE.chunk,
    checkpoint: str | os.PathLike | None = None,
    overwrite: bool = False,
    seed: int = SAMPLE.seed,
    progress: bool = True,
    walkers: int | None = None,
    moves: str | None = None,
    time_limit: float | None = None,
) -> SampleResult:
    """Sample the posterior of ``problem`` starting from the Laplace approximation of ``fit``.

    Args:
        problem: the model and data (as used by :func:`fitting.fit`).
        fit: its point estimate; the starts and the preconditioning come from its Laplace
            approximation (in the sampling coordinates z, :mod:`fitting._posterior`).
        sampler: ``"auto"`` (default, :data:`brdfscale.choices.SAMPLERS`: IMH where the Pareto k̂ of its
            proposal's importance weights is at most 0.7, NUTS otherwise — :class:`fitting.Auto`; NUTS before,
            emcee in earlier releases), ``"nuts"``, ``"hmc"``, ``"emcee"``, ``"imh"``, or a sampler object with its
            settings: :class:`fitting.Emcee` ``(walkers=, moves=)``, :class:`fitting.NUTS`
            ``(warmup=, target_acceptance=, max_doublings=, adapt_mass_matrix=)``,
            :class:`fitting.HMC` ``(trajectory_length=, warmup=, target_acceptance=, jitter=,
            adapt_mass_matrix=)``, :class:`fitting.IMH` ``(dof=, scale=)``,
            :class:`fitting.Auto` ``(imh=, fallback=, max_k=, draws=)``.
        chains: independent chains (default 4): emcee ensembles, or NUTS/HMC chains, each
            started from its own Laplace draw; R̂ compares them.
        steps: steps per trajectory after the warm-up, at least 2 (emcee: all steps, the
            burn-in found afterwards among them; NUTS/HMC: draws after their ``warmup``
            steps); None (default): the sampler's own ``default_steps`` — NUTS/HMC 1000
            draws, IMH 3000 steps, emcee 2000 steps, auto those of the sampler it chooses
            (:data:`brdfscale.choices.SAMPLE`). A resumed run
            continues up to this count; of a checkpoint that holds more, the first are returned.
        chunk: steps between checkpoints (and NUTS/HMC's compiled block of steps).
        checkpoint: HDF5 path; an existing checkpoint of the same run is resumed.
        overwrite: start afresh even if ``checkpoint`` exists (whatever it holds; it is
            replaced when the new, empty checkpoint is in place).
        seed: seed of the starts and of the sampler's random numbers.
        progress: show a progress bar (:func:`brdfscale.show.progress_bar`; every bar is off
            with the environment variable ``BRDFSCALE_PROGRESS=0``).
        walkers, moves: with ``sampler="emcee"``, the :class:`fitting.Emcee` settings
            (walkers per ensemble, default ``max(32, 4·dim)``; ``"stretch"`` or ``"de"``).
        time_limit: seconds (from this call) after which the run ends, with at least two draws after the warm-up
            (NUTS/HMC's warm-up always completes; the chunks of draws are paced to the time left,
            :func:`fitting._sampler.paced`); the result then holds the steps done
            (``SampleResult.stopped``), its status is "not converged" naming the limit, and the checkpoint keeps
            them: a call with the same checkpoint continues the run. None (default): no limit.

    Returns:
        A :class:`SampleResult`; read its ``status`` before trusting the intervals.

    Raises:
        InvalidInputError: ``fit`` is not the :class:`~fitting.FitResult` of ``problem``'s
            model; an unknown ``sampler``; ``walkers``/``moves`` with a sampler object or a
            gradient sampler; ``walkers`` not an integer ≥ 2·dim, ``chains``, ``chunk`` not
            integers ≥ 1, ``steps`` not an integer ≥ 2, ``seed`` not an integer ≥ 0, an unknown
            ``moves``, ``progress`` not a bool, or ``BRDFSCALE_PROGRESS`` set to a value it does
            not accept; ``checkpoint`` belongs to another run (other parameters, sampler or its
            settings, chains, problem data or seed) or to an earlier version's layout.
        MeasurementFileError: ``checkpoint`` is a directory, lies in a directory that does
            not exist, is not a readable checkpoint of :func:`fitting.sample`, or is damaged (a
            chunk fails its SHA-256 check or holds NaN: the message names it and the remedy,
            :func:`fitting.rewind_checkpoint` or ``overwrite=True``), and ``overwrite`` is False.
        OutputWriteError: ``checkpoint`` cannot be written (a full disk — checked before each
            chunk — or an I/O error; the chunks committed before are kept).
        OutputInUseError: another run holds ``checkpoint``.

    ``time_limit`` not a positive number is an InvalidInputError too.
    """
    check_fit(problem, fit, "sample(problem, fit)")
    d = len(problem.model.names)
    rule = resolve_sampler(sampler, walkers, moves)
    chains = integer(chains, "chains", 1)
    if steps is not None:
        steps = integer(steps, "steps", 2)  # one step has no transition: no acceptance, no τ
    chunk = integer(chunk, "chunk", 1)
    seed = integer(seed, "seed", 0)
    if time_limit is not None:
        time_limit = real(time_limit, "time_limit", minimum=0, strict=True)
    deadline = None if time_limit is None else time.monotonic() + time_limit
    overwrite = flag(overwrite, "overwrite")
    progress = flag(progress, "progress")
    if progress:
        progress_mode()  # a BRDFSCALE_PROGRESS it does not accept is refused before any work
    m = sampled_dimension(problem, fit, "sample(problem, fit)")
    # the sampler that runs: the rule's choice (fitting.Auto), or a resumed run's as its checkpoint records it
    recorded = None if checkpoint is None or overwrite else recorded_signature(os.fspath(checkpoint))
    started = time.perf_counter()
    sampler, chosen_by = rule.choose(problem, fit, m=m, chains=chains, seed=seed, recorded=recorded)
    choice_s = time.perf_counter() - started
    steps = integer(sampler.steps_of(steps), "steps", 2)
    settings = sampler.settings(m)
    W = sampler.trajectories(m, chains)

    # the checkpoint is this run's alone until the last chunk is in it: a second run on the same
    # file is refused at once (it would interleave its chunks with ours)
    store = None
    if checkpoint is not None:
        # what makes a chain this run's: not the fit it started from (once resumed, the state
        # comes from the file, and a refit of the same problem need not agree to the last bit)
        signature = {
            "names": list(problem.model.names),
            "sampler": settings,
            "chains": chains,
            "trajectories": W,
            "problem": _digest(problem),
            "seed": seed,
            "coordinates": COORDINATES,
            "undetermined": len(fit.undetermined),
            **({"chosen_by": chosen_by} if chosen_by is not None else {}),
        }
        store = Checkpoint(checkpoint, signature, W, d, chunk, sampler.stats, m)
    lock = contextlib.nullcontext() if store is None else exclusive(store.path, what="checkpoint")
    with lock:
        # with overwrite the old file stays until the new, empty checkpoint replaces it (create)
        resumed = store.load() if store is not None and not overwrite else None
        posterior = target(problem, fit, None if resumed is None else resumed.subspace)
        if store is not None and (resumed is None or resumed.steps == 0):
            # replaces only what the user asked to replace, or a checkpoint of this run with no chunk done
            store.create(replace=overwrite or resumed is not None, subspace=posterior.record())
        chain, log_prob, stats, warmup, timing = sampler.run(
            posterior,
            fit,
            chains=chains,
            steps=steps,
            seed=seed,
            store=store,
            resumed=resumed,
            progress=progress,
            chunk=chunk,
            deadline=deadline,
        )
    if chosen_by is not None:
        timing = {**timing, "choice_s": choice_s}
    asked = sampler.total(steps)
    stopped = None
    if chain.shape[0] < asked:  # only the deadline ends a run early
        stopped = {"time_limit_s": time_limit, "steps": int(chain.shape[0]), "steps_asked": int(asked)}
    return _diagnose(
        posterior, fit, sampler, settings, chains, chain, log_prob, stats, warmup, timing, chosen_by, stopped
    )


def _diagnose(
    posterior, fit, sampler, settings, chains, chain, log_prob, stats, warmup, timing, chosen_by=None, stopped=None
) -> SampleResult:
    problem = posterior.problem
    # τ is NaN for a coordinate no walker moved in (zero variance; short chains, stuck
    # ensembles): taken as ∞ — burn-in half the chain (emcee), ESS 0, τ not reliable (JSON: null)
    n_steps, n_walkers, _ = chain.shape
    burn, warmup = sampler.burn_in(chain, warmup)
    kept = chain[burn:]
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = diag.integrated_time(kept)
        tau = np.where(np.isfinite(tau), tau, np.inf)
        ess = n_walkers * kept.shape[0] / tau
    if "acceptance_rate" in stats:
        acceptance = float(np.mean(stats["acceptance_rate"][burn:]))
    else:
        moved = np.any(np.diff(chain, axis=0) != 0, axis=-1)
        acceptance = float(np.mean(moved))
    quantities = quantities_at(problem.model, chain)  # (steps, W) each, in the model's order
    determined = tuple(n for n in quantities if fit.std.get(n, 0.0) is not None)
    V = undetermined_directions(fit)
    held = [
        {"combination": u.get("combination"), "value": float(v @ np.asarray(fit.theta))}
        for u, v in zip(fit.undetermined, V.T)
    ]
    return SampleResult(
        names=tuple(problem.model.names),
        chain=chain,
        log_prob=log_prob,
        burn=burn,
        tau=tau,
        ess=ess,
        tau_reliable=bool(kept.shape[0] >= 50 * np.max(tau)),
        acceptance=acceptance,
        sampler=sampler.name,
        chains=chains,
        settings=settings,
        warmup=warmup,
        stats=stats,
        quantities=quantities,
        determined=determined,
        undetermined=list(fit.undetermined),
        held=held,
        timing=_timing(timing, burn, n_steps),
        chosen_by=chosen_by,
        stopped=stopped,
    )


def _timing(timing, burn, n_steps) -> dict:
    """NUTS/HMC time their warm-up apart; emcee's burn-in gets its share of the run's steps. A rule's choice of the
    sampler (``choice_s``, :class:`fitting.Auto`) is kept apart."""
    if "run_s" not in timing:
        return dict(timing)
    timed = timing["steps"]
    warm = timing["run_s"] * max(burn - (n_steps - timed), 0) / timed if timed else 0.0
    return {
        "warmup_s": warm,
        "sampling_s": timing["run_s"] - warm,
        **{k: timing[k] for k in ("choice_s",) if k in timing},
    }
