"""The default sampler of :func:`fitting.sample` and ``brdfscale fit``: independence Metropolis–Hastings where the
Laplace approximation covers the posterior, NUTS where it does not — decided before any chain runs.

:class:`fitting.IMH` costs one log-density per step and mixes in a few steps when its proposal q (a Student-t about
the Laplace maximum) is close to the posterior p; where it is not, its chains stick and only R̂ says so afterwards.
Whether q covers p is what the importance weights w = p/q of independent draws of q measure: :class:`Auto` draws
``draws`` of them (:meth:`fitting.IMH.log_weights`) and fits a generalised Pareto tail to the largest weights
(:func:`fitting.pareto_k`, Vehtari, Simpson, Gelman, Yao & Gabry 2024, *Pareto smoothed importance sampling*,
JMLR 25(72)). The chains run with IMH when

    k̂ ≤ min(max_k, 1 − 1/log10(draws))

— the paper's threshold for a reliable importance sampler from that many draws (0.70 and 0.697 at the defaults:
``brdfscale.choices.SAMPLE``) — and with ``fallback`` (NUTS) otherwise. A bounded w makes IMH uniformly ergodic
(Mengersen & Tweedie 1996); k̂ ≤ 0.7 is the practical form of "the tail of w is light enough". The run's
:class:`~fitting.SampleResult` names the sampler that ran and, in ``chosen_by``, k̂, the threshold and the draws;
its status checks the chains as for any sampler.

Measured: k̂ below 0.5 on the anisotropic model's posterior over lobes it describes, above 1 on the parametric
model's from three close scales at 10 % noise, where IMH's chains stick (tests/test_fit_slow.py); the speed
benchmark's rows record theirs (``experiments/bench_anisotropic.py``; docs/fitting.md, "Speed of the default fit").

A checkpoint records the choice in its signature: a resumed run continues with the sampler that wrote it, whatever
a recomputed k̂ would say. Verified in tests/test_samplers.py.
"""

import dataclasses
import json
import math

from brdfscale import InvalidInputError
from brdfscale.checks import integer, real
from brdfscale.choices import SAMPLE

from ._diagnostics import pareto_k
from ._posterior import target
from ._sample_blackjax import NUTS
from ._sample_imh import IMH
from ._sampler import AbstractChoice, AbstractSampler


__all__ = ["Auto"]


@dataclasses.dataclass(frozen=True)
class Auto(AbstractChoice):
    """IMH where the Pareto k̂ of its proposal's importance weights is at most the threshold, ``fallback``
    otherwise (module docstring).

    Args:
        imh: the independence sampler tried first (default :class:`fitting.IMH` ``()``).
        fallback: the sampler where IMH's proposal does not cover the posterior (default :class:`fitting.NUTS`
            ``()``; any sampler object).
        max_k: the largest k̂ for IMH (default ``SAMPLE.auto_max_k``, 0.7); the threshold is
            ``min(max_k, 1 − 1/log10(draws))``.
        draws: proposal draws weighed for k̂ (default ``SAMPLE.auto_draws``, 2000), one log-density each.
    """

    imh: IMH = IMH()
    fallback: AbstractSampler = NUTS()
    max_k: float = SAMPLE.auto_max_k
    draws: int = SAMPLE.auto_draws
    name = "auto"

    def __post_init__(self):
        if not isinstance(self.imh, IMH):
            raise InvalidInputError(f"imh must be a fitting.IMH; got {type(self.imh).__name__}.")
        if not isinstance(self.fallback, AbstractSampler):
            raise InvalidInputError(
                "fallback must be a sampler object (fitting.NUTS, fitting.HMC, fitting.Emcee, fitting.IMH); "
                f"got {type(self.fallback).__name__}."
            )
        object.__setattr__(self, "max_k", real(self.max_k, "max_k"))
        object.__setattr__(self, "draws", integer(self.draws, "draws", 100))

    @property
    def limit(self) -> float:
        """The largest k̂ for which IMH runs: ``min(max_k, 1 − 1/log10(draws))``."""
        return min(self.max_k, 1 - 1 / math.log10(self.draws))

    def check_batched(self) -> None:
        raise InvalidInputError(
            "sample_many samples with NUTS or HMC only (one program over many materials' posteriors); auto chooses "
            "per posterior: use fitting.sample(problem, fit) per material, or sampler='nuts' here."
        )

    def choose(self, problem, fit, *, m, chains, seed, recorded) -> tuple[AbstractSampler, dict | None]:
        """IMH or ``fallback`` by k̂ (module docstring), or the one ``recorded`` names (a resumed run's)."""
        recorded = recorded or {}
        earlier = recorded.get("chosen_by")
        if isinstance(earlier, dict) and earlier.get("name") == self.name:
            for option in (self.imh, self.fallback):
                if _same(recorded.get("sampler"), option.settings(m)):
                    return option, earlier
        weights = self.imh.log_weights(target(problem, fit), fit, draws=self.draws, seed=seed, batch=chains)
        k = pareto_k(weights)
        chosen = self.imh if k <= self.limit else self.fallback
        return chosen, {
            "name": self.name,
            "chose": chosen.name,
            "pareto_k": k if math.isfinite(k) else None,  # None: too few weights in the tail to fit one (∞)
            "limit": self.limit,
            "draws": self.draws,
        }


def _same(a, b) -> bool:
    """Whether two samplers' settings records are equal as a checkpoint's JSON holds them."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
