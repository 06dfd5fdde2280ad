"""The abstract samplers of :func:`fitting.sample`: what :class:`fitting.Emcee`, :class:`fitting.NUTS`,
:class:`fitting.HMC`, :class:`fitting.IMH` and :class:`fitting.Auto` implement, so that ``sample`` and
``sample_many`` ask the object instead of testing its type.

What ``sample(..., sampler=)`` accepts is an :class:`AbstractChoice`: it names itself (``name``: the key of
:data:`fitting.SAMPLERS`), answers for the arguments that belong to one sampler only (:meth:`~AbstractChoice.from_name`,
:meth:`~AbstractChoice.refuse_walkers`) and for being vectorised over materials (:meth:`~AbstractChoice.check_batched`),
and says which sampler runs the chains of a posterior (:meth:`~AbstractChoice.choose`): a sampler itself, or
:class:`fitting.Auto`'s pick by the posterior's fit.

A sampler (:class:`AbstractSampler`) is a frozen dataclass of its settings (checked when made) that

* records its per-step statistics (``stats``: name → HDF5 dtype);
* says how many steps it runs when ``sample`` is given none (``default_steps``: emcee's
  ensembles need long chains, the Laplace-preconditioned gradient samplers far fewer draws for
  the same effective sample size — :data:`brdfscale.choices.SAMPLE`; :meth:`steps_of`);
* says what a checkpoint records of it (:meth:`settings`) and how many trajectories ``chains``
  independent chains have (:meth:`trajectories`);
* runs the chains (:meth:`run`) and finds the burn-in of the run (:meth:`burn_in`).
"""

import abc
import time
from typing import ClassVar

import numpy as np

from brdfscale import InvalidInputError


__all__ = ["AbstractChoice", "AbstractSampler"]


PROBE = 8
"""Steps of a time-limited run's first chunk of draws where the call has no pace measured yet (:func:`paced`)."""


def out_of_time(deadline: float | None, drawn: int) -> bool:
    """Whether a run given a ``deadline`` (a ``time.monotonic()`` reading: :func:`fitting.sample`'s ``time_limit``)
    stops before its next chunk: the deadline has passed and at least two draws after any warm-up are in (a chain
    needs two for a transition; the warm-up always completes, as no draw is possible without it)."""
    return deadline is not None and drawn >= 2 and time.monotonic() >= deadline


def paced(n: int, deadline: float | None, seconds: float, steps: int, drawn: int) -> int:
    """The steps of a run's next chunk of draws, at most ``n``: with a ``deadline``, as many as the time left allows
    at the pace this call has measured (``seconds`` computing ``steps``), at least one and at least what brings the
    draws to two; :data:`PROBE` steps where no pace is measured yet; past the deadline, only what brings the draws
    to two. A limit is then overrun by about a step, not by a chunk (the chunking changes no draw)."""
    if deadline is None:
        return n
    left = deadline - time.monotonic()
    if left <= 0:
        return max(min(n, 2 - drawn), 1)
    if steps <= 0 or seconds <= 0:
        return min(n, PROBE)
    return max(min(n, int(left / (seconds / steps))), 2 - drawn, 1)


class AbstractChoice(abc.ABC):
    """What :func:`fitting.sample` accepts as ``sampler=`` (module docstring): a sampler, or a rule that picks one."""

    name: ClassVar[str] = ""

    @abc.abstractmethod
    def choose(
        self, problem, fit, *, m: int, chains: int, seed: int, recorded: dict | None
    ) -> tuple["AbstractSampler", dict | None]:
        """The sampler that runs the chains of ``problem``'s posterior about ``fit`` (``m`` sampled coordinates,
        ``chains`` chains, ``seed``), and the record of the choice (None: nothing was chosen). ``recorded``: the
        signature a checkpoint of this run holds (None: none), so that a resumed run continues with the sampler that
        wrote it."""

    @classmethod
    def from_name(cls, walkers=None, moves=None) -> "AbstractChoice":
        """The sampler chosen by name (``sample(..., sampler="nuts")``), with ``sample``'s
        ``walkers=``/``moves=`` where this sampler takes them; InvalidInputError otherwise."""
        if walkers is not None or moves is not None:
            raise InvalidInputError(
                f"walkers= and moves= with a sampler object: they apply to emcee only, not {cls.name}."
            )
        return cls()

    def refuse_walkers(self) -> InvalidInputError:
        """The error for ``walkers=``/``moves=`` given beside this sampler object."""
        return InvalidInputError(
            f"walkers= and moves= with a sampler object: they apply to emcee only, not {self.name}."
        )

    def check_batched(self) -> None:
        """InvalidInputError unless this sampler runs many materials' posteriors in one
        program (:func:`fitting.sample_many`)."""


class AbstractSampler(AbstractChoice):
    """The interface every sampler of :func:`fitting.sample` implements (module docstring)."""

    stats: ClassVar[dict] = {}
    default_steps: ClassVar[int] = 0

    def choose(self, problem, fit, *, m, chains, seed, recorded) -> tuple["AbstractSampler", dict | None]:
        """This sampler: it runs the chains itself."""
        return self, None

    def steps_of(self, steps) -> int:
        """``steps`` as given, or this sampler's :attr:`default_steps` where it is None (the
        default of :func:`fitting.sample`, :func:`fitting.sample_many` and ``brdfscale fit``)."""
        return self.default_steps if steps is None else steps

    def total(self, steps: int) -> int:
        """The steps a run of ``steps`` holds when complete (NUTS/HMC: their warm-up too)."""
        return steps

    @abc.abstractmethod
    def settings(self, d: int) -> dict:
        """What the checkpoint records of this sampler for a sampled dimension ``d``."""

    @abc.abstractmethod
    def trajectories(self, d: int, chains: int) -> int:
        """The trajectories of ``chains`` independent chains in dimension ``d``."""

    @abc.abstractmethod
    def run(
        self, target, fit, *, chains, steps, seed, store, resumed, progress, chunk, deadline=None
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], dict | None, dict[str, float]]:
        """The chain (steps, W, d) in θ, log p(θ) (steps, W), per-step statistics, the warm-up
        record (or None) and the timing; resumed from ``resumed`` where it holds steps, each
        chunk appended to ``store``; ended early, between chunks, where :func:`out_of_time`
        says so for ``deadline``."""

    @abc.abstractmethod
    def burn_in(self, chain, warmup) -> tuple[int, dict | None]:
        """The steps of ``chain`` (steps, W, d) discarded as burn-in, and the warm-up record
        (``warmup``, :meth:`run`'s, or the burn-in's own when the sampler finds it afterwards)."""
