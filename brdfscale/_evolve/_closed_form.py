"""The closed-form path: Gaussian/δ/mixture algebra (:mod:`._algebra`), exact.

:class:`ClosedForm` applies where the lobe's and statistics' families allow it
(:func:`._algebra.has_closed_form`: structure only, the same under ``jax.jit``) and has
nothing to discretise: resolving it returns it as it is, evaluating it convolves the lobe with
``s_from`` and deconvolves ``s_to`` (``NoBRDFAtScaleError`` where a Gaussian would need a
negative variance: checked when built from concrete values, at run time otherwise).
"""

from .._errors import MethodNotApplicableError
from ..lobes import AbstractLobe, Lobe
from ._algebra import convolve, deconvolve, has_closed_form
from ._method import AbstractMethod


class ClosedForm(AbstractMethod):
    """Gaussian/δ/mixture algebra (exact); :class:`brdfscale.MethodNotApplicableError` where the
    families have no closed form."""

    def explain(self) -> str:
        return "closed form (Gaussian/δ/mixture algebra): exact"

    def applicable(self, lobe, s_from, s_to) -> bool:
        return has_closed_form(lobe.shape, s_from, s_to)

    def choose(self, lobe, s_from, s_to) -> AbstractMethod:
        if not self.applicable(lobe, s_from, s_to):
            raise MethodNotApplicableError(
                f"no closed form for a {type(lobe.shape).__name__} lobe with {type(s_from).__name__} → "
                f"{type(s_to).__name__} statistics; closed forms exist for Gaussian/Beckmann lobes and "
                "statistics (and mixtures of them), δ (Mirror) lobes, and δ statistics. Use method='grid'."
            )
        return self

    def resolve(self, lobe, s_from, s_to, *, tol, regularisation, rule, noise, check) -> AbstractMethod:
        return self.choose(lobe, s_from, s_to)

    def evaluate(self, lobe, s_from, s_to, *, tol, regularisation, rule, noise, check) -> AbstractLobe:
        """``lobe ∗ s_from`` deconvolved by ``s_to`` in closed form; ``regularisation`` is not
        used (nothing is divided numerically)."""
        self.choose(lobe, s_from, s_to)
        numerator = convolve(lobe.shape, s_from)
        shape = None if numerator is None else deconvolve(numerator, s_to, check)
        assert shape is not None  # has_closed_form holds exactly where the algebra answers
        return Lobe(shape, lobe.amplitude)
