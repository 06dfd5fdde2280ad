"""Posterior sampling with emcee: vectorised jit log-probability, chunked HDF5 checkpoints.

Posterior (in the unconstrained coordinates θ of the model):

    log p(θ | data) = −½ χ²(θ) + log π(θ),

with ``r`` the whitened residuals of :class:`fitting.Problem` (Gaussian noise of the stated
σ; smoothness rows of the non-parametric model are part of the prior) and ``π`` uniform on
the model's prior box ``lo ≤ θ ≤ hi`` — for the parametric model that is a log-uniform
(scale-invariant) prior on every positive parameter over the ranges listed in
docs/fitting.md. Outside the box, and wherever the log-probability is not finite, it is
−∞.

The affine-invariant ensemble (emcee's stretch move; DE moves selectable) runs in chunks of
``chunk`` steps. With a checkpoint path, each chunk is appended to an HDF5 file (chunked
float64 datasets ``chain`` (step, walker, θ) and ``log_prob`` (step, walker)) together with
the random state of the sampler, and the step counter ``steps_done`` is written last: an
interrupted run (Ctrl-C, crash, kill) resumes from the last completed chunk and yields the
very same chain, bit for bit, as an uninterrupted one.

Diagnostics: the integrated autocorrelation time τ per coordinate (emcee's estimator on
the chain after burn-in), the effective sample size ``ESS = walkers · steps / τ``, and
whether the chain is long enough (≥ 50 τ) for τ itself to be trusted — reported, never
silenced. A coordinate in which no walker moved (a very short or stuck chain) has τ = ∞:
ESS 0, τ not reliable, burn-in half the chain.
"""

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import InvalidInputError, MeasurementFileError
from brdfscale.files import atomic_write, exclusive
from brdfscale.show import Shown, Table, progress_bar, progress_mode

from brdfscale.checks import flag, integer
from ._estimate import FitResult, Problem, check_fit


def _emcee():
    """emcee, imported on first use (``import fitting`` stays light: the command line's start-up)."""
    import emcee

    return emcee


def _h5py():
    """h5py, imported on first use (the checkpoints)."""
    import h5py

    return h5py

__all__ = ["SampleResult", "sample", "log_posterior"]

_MOVES = {
    "stretch": lambda: _emcee().moves.StretchMove(),
    "de": lambda: [(_emcee().moves.DEMove(), 0.8), (_emcee().moves.DESnookerMove(), 0.2)],
}


def log_posterior(theta, problem: Problem):
    """``−½‖r(θ)‖²`` inside the prior box, −∞ outside or where not finite."""
    lp = -0.5 * problem.chi2(theta)
    inside = jnp.all((theta >= problem.lower) & (theta <= problem.upper))
    return jnp.where(inside & jnp.isfinite(lp), lp, -jnp.inf)


@eqx.filter_jit
def _batched_log_posterior(thetas, problem):
    return jax.vmap(log_posterior, in_axes=(0, None))(thetas, problem)


@dataclasses.dataclass(repr=False)
class SampleResult(Shown):
    """The chain and its diagnostics; ``samples`` is the flattened chain after burn-in."""

    names: tuple[str, ...]
    chain: np.ndarray
    log_prob: np.ndarray
    burn: int
    tau: np.ndarray
    ess: np.ndarray
    tau_reliable: bool
    acceptance: float

    @property
    def samples(self) -> np.ndarray:
        return self.chain[self.burn:].reshape(-1, self.chain.shape[-1])

    def _show_items(self):
        n_steps, n_walkers, _ = self.chain.shape
        return [("walkers", n_walkers), ("steps", n_steps), ("burn_in", self.burn),
                ("draws", (n_steps - self.burn) * n_walkers), ("acceptance", self.acceptance),
                ("tau_max", float(np.max(self.tau))), ("ess_min", float(np.min(self.ess))),
                ("tau_reliable", self.tau_reliable), ("chain", self.chain)]

    def _show_tables(self):
        flat = self.samples
        rows = [(name, float(np.mean(flat[:, i])), float(np.std(flat[:, i])), float(self.tau[i]), float(self.ess[i]))
                for i, name in enumerate(self.names)]
        return [Table("coordinates after burn-in (θ: the model's unconstrained coordinates)",
                      ("coordinate", "mean", "std", "τ (steps)", "ESS"), rows)]

    def plot(self, **options):
        """The chains (trace plots, burn-in marked): :func:`brdfscale.plot.chains` (options as
        there); returns a ``matplotlib.figure.Figure``."""
        from brdfscale import plot

        return plot.chains(self, **options)

    def diagnostics(self) -> dict:
        n_steps, n_walkers, _ = self.chain.shape
        return {
            "walkers": n_walkers,
            "steps": n_steps,
            "burn_in": self.burn,
            "acceptance_fraction": self.acceptance,
            "autocorrelation_time": dict(zip(self.names, self.tau.tolist())),
            "effective_sample_size": dict(zip(self.names, self.ess.tolist())),
            "tau_reliable": self.tau_reliable,
            "tau_note": (
                "chain ≥ 50 τ after burn-in: τ estimate reliable" if self.tau_reliable else
                "chain shorter than 50 τ after burn-in: τ (and hence ESS) is a lower-bound estimate; run longer"
            ),
        }


class _Checkpoint:
    """An HDF5 file holding the chain so far and the sampler's state after the last chunk."""

    _EXPECTED = "an HDF5 checkpoint written by fitting.sample"

    def __init__(self, path, names, n_walkers, chunk, run: dict):
        self.path, self.names, self.n_walkers, self.chunk = os.fspath(path), tuple(names), n_walkers, chunk
        # what else makes a chain this run's: the problem's digest, the seed, the moves (not the
        # fit it started from: once resumed, the state comes from the file, and a refit of the
        # same problem need not agree to the last bit)
        self.run = run
        if os.path.isdir(self.path):
            raise MeasurementFileError(f"checkpoint {self.path} is a directory; expected the path of {self._EXPECTED} "
                                       "(e.g. DIR/chain.h5).")
        directory = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(directory):
            raise MeasurementFileError(f"checkpoint {self.path}: directory {directory} does not exist; create it "
                                       "or choose another checkpoint path.")

    def _signature(self, legacy: bool = False):
        """The run's identity in the file: parameters and walkers, and (since checkpoints record
        it) the problem's digest, the seed and the moves."""
        identity = {"names": list(self.names), "walkers": self.n_walkers}
        return json.dumps(identity if legacy else {**identity, **self.run})

    def load(self):
        """``(chain, log_prob, random_state)`` of the completed steps (``random_state`` None
        when no chunk was completed), or None if there is no file."""
        if not os.path.exists(self.path):
            return None
        retry = "use another path, or pass overwrite=True (CLI: --force) to start afresh."
        try:
            f = _h5py().File(self.path, "r")
        except OSError as err:
            raise MeasurementFileError(f"checkpoint {self.path} cannot be read as {self._EXPECTED} ({err}); {retry}") from None
        with f:
            signature = f.attrs.get("signature")
            if signature is None or "steps_done" not in f.attrs or not {"chain", "log_prob", "rng_keys"} <= set(f):
                raise MeasurementFileError(f"{self.path} is not {self._EXPECTED} (it lacks the signature, steps_done, "
                                           f"chain, log_prob or rng_keys entries); {retry}")
            if signature == self._signature(legacy=True):
                warnings.warn(f"checkpoint {self.path} predates the recording of the problem, seed and moves; "
                              "resuming it assumes they are the same as in this call.", stacklevel=3)
            elif signature != self._signature():
                raise InvalidInputError(
                    f"checkpoint {self.path} belongs to a different run (its record: {signature}; this run: "
                    f"{self._signature()}); use another path or pass overwrite=True."
                )
            try:
                done = int(f.attrs["steps_done"])
                chain, log_prob = f["chain"][:done], f["log_prob"][:done]
                state = None
                if done > 0:
                    state = ("MT19937", f["rng_keys"][:], int(f.attrs["rng_pos"]), int(f.attrs["rng_has_gauss"]),
                             float(f.attrs["rng_cached_gaussian"]))
            except (OSError, KeyError, ValueError, TypeError) as err:
                raise MeasurementFileError(f"checkpoint {self.path} is damaged ({err}); {retry}") from None
        shape = (done, self.n_walkers, len(self.names))
        if chain.shape != shape or log_prob.shape != shape[:2]:
            raise MeasurementFileError(f"checkpoint {self.path} is damaged (steps_done = {done}, but chain has shape "
                                       f"{chain.shape} and log_prob {log_prob.shape}); {retry}")
        return chain, log_prob, state

    def create(self, replace: bool):
        """A checkpoint with no steps, written atomically (a hidden temporary file in the same
        directory, moved into place); an existing file is replaced only when ``replace``."""
        def write(tmp):
            with _h5py().File(tmp, "w") as f:
                d = len(self.names)
                f.create_dataset("chain", (0, self.n_walkers, d), maxshape=(None, self.n_walkers, d),
                                 chunks=(self.chunk, self.n_walkers, d), dtype="f8")
                f.create_dataset("log_prob", (0, self.n_walkers), maxshape=(None, self.n_walkers),
                                 chunks=(self.chunk, self.n_walkers), dtype="f8")
                f.create_dataset("rng_keys", (624,), dtype="u4")
                f.attrs["signature"] = self._signature()
                f.attrs["steps_done"] = 0

        try:
            atomic_write(self.path, write, overwrite=replace, error=MeasurementFileError)
        except OSError as err:
            raise MeasurementFileError(f"checkpoint {self.path} cannot be written: {err}") from None

    def append(self, chain, log_prob, random_state):
        try:
            with _h5py().File(self.path, "r+") as f:
                done = int(f.attrs["steps_done"])
                n = done + chain.shape[0]
                for name, block in (("chain", chain), ("log_prob", log_prob)):
                    f[name].resize(n, axis=0)
                    f[name][done:n] = block
                f["rng_keys"][:] = random_state[1]
                f.attrs["rng_pos"], f.attrs["rng_has_gauss"] = int(random_state[2]), int(random_state[3])
                f.attrs["rng_cached_gaussian"] = float(random_state[4])
                f.flush()
                f.attrs["steps_done"] = n  # the commit marker, written last
        except OSError as err:
            raise MeasurementFileError(f"checkpoint {self.path} cannot be updated: {err}") from None


def _digest(tree) -> str:
    """SHA-256 of a pytree: its structure (which holds the static fields — a model's families,
    law, fixed values, quadrature settings) and its arrays (dtypes, shapes and bytes)."""
    h = hashlib.sha256(str(jax.tree_util.tree_structure(tree)).encode())
    for leaf in jax.tree_util.tree_leaves(tree):
        a = np.ascontiguousarray(np.asarray(leaf))
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()[:32]


def _initial_walkers(fit: FitResult, lo, hi, n_walkers, rng):
    """A small ball around the optimum: Laplace draws (×0.1) plus 1e-3 jitter in every direction."""
    d = fit.theta.size
    chol = np.linalg.cholesky(fit.covariance + 1e-12 * np.eye(d))
    p0 = fit.theta + 0.1 * rng.standard_normal((n_walkers, d)) @ chol.T + 1e-3 * rng.standard_normal((n_walkers, d))
    return np.clip(p0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))


def sample(
    problem: Problem,
    fit: FitResult,
    *,
    walkers: int | None = None,
    steps: int = 2000,
    chunk: int = 200,
    checkpoint: str | os.PathLike | None = None,
    overwrite: bool = False,
    moves: str = "stretch",
    seed: int = 0,
    progress: bool = True,
) -> SampleResult:
    """Sample the posterior of ``problem`` starting near the optimum of ``fit``.

    Args:
        problem: the model and data (as used by :func:`fitting.fit`).
        fit: its point estimate; walkers start in a small Laplace ball around it.
        walkers: ensemble size (default ``max(32, 4·dim)``, even).
        steps: total steps, at least 2 (a resumed run continues up to this count; of a
            checkpoint that holds more, the first ``steps`` are returned).
        chunk: steps between checkpoints.
        checkpoint: HDF5 path; an existing compatible file is resumed.
        overwrite: start afresh even if ``checkpoint`` exists (whatever it holds; it is
            replaced when the new, empty checkpoint is in place).
        moves: ``"stretch"`` (default) or ``"de"`` (differential evolution + snooker).
        seed: seed of the initial ball and of the sampler's random state.
        progress: show a progress bar (:func:`brdfscale.show.progress_bar`: the notebook widget
            in Jupyter with ipywidgets, else text on stderr; every bar is off with the
            environment variable ``BRDFSCALE_PROGRESS=0``).

    Raises:
        InvalidInputError: ``fit`` is not the :class:`~fitting.FitResult` of ``problem``'s
            model; ``walkers`` not an integer ≥ 2·dim, ``steps`` not an integer ≥ 2,
            ``chunk`` not an integer ≥ 1, ``seed`` not an integer ≥ 0, an unknown ``moves``,
            ``progress`` not a bool, or ``BRDFSCALE_PROGRESS`` set to a value it does not accept;
            ``checkpoint`` belongs to another run (other parameters, walkers, problem data,
            seed or moves).
        MeasurementFileError: ``checkpoint`` is a directory, lies in a directory that does
            not exist, is not a readable checkpoint of :func:`fitting.sample` (and
            ``overwrite`` is False), or cannot be written.
    """
    check_fit(problem, fit, "sample(problem, fit)")
    d = len(problem.model.names)
    if walkers is None:
        walkers = max(32, 4 * d)
    walkers = integer(walkers, "walkers", 2 * d)
    walkers += walkers % 2
    steps = integer(steps, "steps", 2)  # one step has no transition: no acceptance, no τ
    chunk = integer(chunk, "chunk", 1)
    seed = integer(seed, "seed", 0)
    overwrite = flag(overwrite, "overwrite")
    progress = flag(progress, "progress")
    if progress:
        progress_mode()  # a BRDFSCALE_PROGRESS it does not accept is refused before any work
    if not isinstance(moves, str) or moves not in _MOVES:
        raise InvalidInputError(f"moves must be one of {sorted(_MOVES)}; got {moves!r}.")
    lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)

    def logp(thetas):
        out = np.asarray(_batched_log_posterior(jnp.asarray(thetas), problem))
        return np.where(np.isfinite(out), out, -np.inf)

    # the checkpoint is this run's alone until the last chunk is in it: a second run on the same
    # file is refused at once (it would interleave its chunks with ours)
    store = None
    if checkpoint is not None:
        store = _Checkpoint(checkpoint, problem.model.names, walkers, chunk,
                            {"problem": _digest(problem), "seed": seed, "moves": moves})
    lock = contextlib.nullcontext() if store is None else exclusive(store.path, what="checkpoint")
    with lock:
        chains, log_probs = _run_chain(fit, logp, d, lo, hi, walkers, steps, chunk, seed, moves, store,
                                       overwrite, progress)
    chain, log_prob = np.concatenate(chains), np.concatenate(log_probs)
    return _diagnose(problem.model.names, chain, log_prob)



def _run_chain(fit, logp, d, lo, hi, walkers, steps, chunk, seed, moves, store, overwrite, progress):
    """The chunks of the chain: resumed from the checkpoint ``store`` where it holds some, each
    new one appended to it as soon as it is sampled (the caller holds the checkpoint's lock)."""
    rng = np.random.default_rng(seed)
    chains, log_probs = [], []
    # with overwrite the old file stays until the new, empty checkpoint replaces it (create)
    resumed = store.load() if store is not None and not overwrite else None
    sampler = _emcee().EnsembleSampler(walkers, d, logp, vectorize=True, moves=_MOVES[moves]())
    if resumed is not None and resumed[0].shape[0] > 0:
        chain, log_prob, random_state = resumed
        # a checkpoint longer than asked: its first `steps` steps are the chain of a run of `steps`
        chains, log_probs = [chain[:steps]], [log_prob[:steps]]
        state = _emcee().State(chain[-1], log_prob=log_prob[-1], random_state=random_state)
    else:
        if store is not None:
            # replaces only what the user asked to replace, or a checkpoint of this run with no chunk done
            store.create(replace=overwrite or resumed is not None)
        sampler.random_state = np.random.RandomState(seed).get_state()
        p0 = _initial_walkers(fit, lo, hi, walkers, rng)
        state = _emcee().State(p0, log_prob=logp(p0), random_state=sampler.random_state)
    done = sum(c.shape[0] for c in chains)
    with progress_bar(enabled=progress, total=steps, initial=done, desc="emcee", unit="step") as bar:
        while done < steps:
            n = min(chunk, steps - done)
            block, block_lp = np.empty((n, walkers, d)), np.empty((n, walkers))
            for j, state in enumerate(sampler.sample(state, iterations=n, store=False)):
                block[j], block_lp[j] = state.coords, state.log_prob
                bar.update(1)
            state.random_state = sampler.random_state
            if store is not None:
                store.append(block, block_lp, state.random_state)
            chains.append(block)
            log_probs.append(block_lp)
            done += n
    return chains, log_probs

def _integrated_time(chain):
    # quiet=True logs a warning for short chains; the shortfall is reported in tau_reliable instead
    logger = logging.getLogger("emcee.autocorr")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        return _emcee().autocorr.integrated_time(chain, quiet=True)
    finally:
        logger.setLevel(level)


def _diagnose(names, chain, log_prob) -> SampleResult:
    # τ is NaN for a coordinate no walker moved in (zero variance; short chains, stuck
    # ensembles): taken as ∞ — burn-in half the chain, ESS 0, τ not reliable (JSON: null)
    n_steps, n_walkers, _ = chain.shape
    with np.errstate(invalid="ignore", divide="ignore"):
        tau_all = _integrated_time(chain)
        burn = int(min(np.ceil(2 * np.max(tau_all)), n_steps // 2)) if np.all(np.isfinite(tau_all)) else n_steps // 2
        kept = chain[burn:]
        tau = _integrated_time(kept)
        tau = np.where(np.isfinite(tau), tau, np.inf)
        ess = n_walkers * kept.shape[0] / tau
    moved = np.any(np.diff(chain, axis=0) != 0, axis=-1)
    return SampleResult(
        names=tuple(names), chain=chain, log_prob=log_prob, burn=burn, tau=tau, ess=ess,
        tau_reliable=bool(kept.shape[0] >= 50 * np.max(tau)), acceptance=float(np.mean(moved)),
    )
