"""The evolution operator's paths as objects that carry their behaviour (lineax's solver pattern).

A *method* says how :func:`brdfscale.evolve` inverts the evolved transform
``G_to = G_from S_from / S_to`` (seed Eq. 4.4). Each path is a final class in its own module:

* :class:`~brdfscale.ClosedForm` (``_closed_form.py``) — Gaussian/δ/mixture algebra: exact,
  nothing to discretise;
* :class:`~brdfscale.Radial` (``_radial.py``) — radially symmetric inputs:
  ``g(r) = (2π)⁻¹ ∫_0^K G(k) J₀(kr) k dk`` by an n-node Gauss–Legendre rule on [0, K],
  evaluated at the queries or on a verified table of radii read off by 8-point Lagrange
  interpolation;
* :class:`~brdfscale.Grid` (``_grid.py``) — general inputs: ``G`` on an N × N real-FFT
  frequency grid over the slope half-width a, inverted at the queries (direct sums) or onto a
  finer slope grid (zero-padded inverse FFT) read off by 6 × 6-point Lagrange interpolation;
* :class:`~brdfscale.Auto` (``_auto.py``) — the first of these that applies.

Every method answers, for given inputs, :meth:`AbstractMethod.applicable` (structure only),
:meth:`AbstractMethod.choose` (the path that handles them: itself, or for ``Auto`` the first
that applies), :meth:`AbstractMethod.resolve` (the discretisation from concrete values — what
:func:`brdfscale.select` returns), :meth:`AbstractMethod.evaluate` (the evolved lobe — what
:func:`brdfscale.evolve` returns) and :meth:`AbstractMethod.explain`. :mod:`._flow` is the one
evolve/select flow that asks them; nothing else dispatches on the method's type.

A method whose discretisation is not given is *unresolved*. :func:`brdfscale.select` resolves
one from concrete parameter values (nodes, cut-off, grid side and extent, interpolation
tables — each verified against the tolerance it reports); :func:`brdfscale.evolve` resolves
itself when the values are concrete. Under ``jax.jit``/``grad``/``vmap`` the values are traced
and unknown, so an unresolved spectral method is refused (:class:`UnresolvedMethodError`)
instead of falling back to a default size: resolve outside the transformation and pass the
resolved object in. A method with an explicit ``nodes`` (radial) or ``size`` (grid) but no
cut-off or extent is resolved at run time from the traced values themselves (the cut-off by
the spectral probe, the extent from the support radius): sizes are static, values are not.
"""

import abc
import os
import sys

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._errors import InvalidInputError
from .._show import Shown
from .._validation import integer, is_concrete, real
from ..lobes import AbstractLobe


MIN_TOL = 1e-14
"""The smallest ``tol`` accepted: float64 rounding in the evaluation exceeds anything below."""


def achievable_tol(dtype) -> float:
    """The smallest error relative to the lobe's peak an evaluation in ``dtype`` can honour:
    :data:`MIN_TOL` (float64's floor) scaled by the ratio of machine epsilons,
    ``MIN_TOL · eps(dtype)/eps(float64)`` — about 5e-6 in float32
    (``tests/test_evaluation_contract.py::test_float32_explain_states_the_tolerance_float32_can_honour``)."""
    return MIN_TOL * float(jnp.finfo(dtype).eps) / float(np.finfo(np.float64).eps)


class AbstractMethod(Shown, eqx.Module):
    """How :func:`brdfscale.evolve` evaluates the evolved lobe (module docstring). Abstract;
    the paths are final subclasses, each owning its behaviour."""

    _show_hidden = ("budget", "sign_check", "regularisation_note", "dtype")

    @property
    def path(self) -> str:
        return type(self).__name__.lower().replace("closedform", "closed_form")

    @property
    def resolved(self) -> bool:
        """Whether every discretisation choice is fixed (no value-dependent choice left)."""
        return True

    @abc.abstractmethod
    def applicable(self, lobe, s_from, s_to) -> bool:
        """Whether this method can evolve ``lobe`` (a :mod:`brdfscale.lobes` lobe) between
        these statistics: structure only (families and isotropy, never values), so the
        answer is the same under ``jax.jit``."""

    @abc.abstractmethod
    def choose(self, lobe, s_from, s_to) -> "AbstractMethod":
        """The path that evolves these inputs, unresolved as given (structure only);
        :class:`brdfscale.MethodNotApplicableError` when this method does not apply."""

    @abc.abstractmethod
    def resolve(self, lobe, s_from, s_to, *, tol: float, regularisation, rule, noise, check: bool) -> "AbstractMethod":
        """The method with every discretisation choice made and verified for these concrete
        values (:func:`brdfscale.select`; arguments as checked by ``check_arguments``:
        ``regularisation`` a λ array or None, ``rule`` a rule's name or None)."""

    @abc.abstractmethod
    def evaluate(self, lobe, s_from, s_to, *, tol: float, regularisation, rule, noise, check: bool) -> AbstractLobe:
        """The lobe at the target scale (:func:`brdfscale.evolve`; arguments as for
        :meth:`resolve`)."""

    @abc.abstractmethod
    def explain(self) -> str:
        """What the method computes, in words."""

    def with_sizes(self, size, extent) -> "AbstractMethod":
        """The string API's ``size=``/``extent=`` put into this path (nothing to put for paths
        without a discretisation)."""
        return self


def optional_array(x):
    """Floats of a method as array leaves (a changed value recompiles nothing)."""
    if x is None:
        return None
    try:
        return jnp.asarray(x, dtype=jnp.result_type(float))
    except TypeError:
        raise InvalidInputError(f"expected a real number; got {type(x).__name__}.") from None


def number(x) -> float | None:
    return None if x is None or not is_concrete(x) else float(x)


def lambda_note(method) -> str:
    if method.regularisation is None:
        return ""
    value = number(method.regularisation)
    text = "traced" if value is None else f"{value:.3g}"
    detail = "" if method.regularisation_note is None else f" ({method.regularisation_note})"
    return f"; Tikhonov λ = {text}{detail}"


def tol_note(tol: float | None, dtype: str | None, asked: float | None = None) -> str:
    """``explain()``'s statement of the error honoured: ``tol`` as resolved, or — when the
    evaluation's floating ``dtype`` cannot honour it — the floor that dtype can
    (:func:`achievable_tol`) and that ``tol`` was asked; ``asked``: the tighter ``tol`` asked
    when the discretisation could honour only ``tol`` (a capped grid)."""
    if tol is None:
        return ""
    if asked is not None and asked < tol:
        return f"; honours tol = {tol:.3g} of the peak (tol = {asked:.3g} was asked: the capped grid cannot resolve it)"
    if dtype is not None:
        floor = achievable_tol(dtype)
        if tol < floor:
            return (
                f"; honours about {floor:.2g} of the peak in {dtype} (tol = {tol:.3g} was asked: "
                f"below what {dtype} rounding can give)"
            )
    return f"; honours tol = {tol:.3g} of the peak"


_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
_EQUINOX = os.path.dirname(os.path.abspath(eqx.__file__)) + os.sep


def caller_stacklevel() -> int:
    """The ``stacklevel`` with which a warning raised by the calling function names the first
    line outside brdfscale (and equinox's method wrappers): the user's call of ``evolve``,
    ``select`` or ``density``, however deep the paths' methods sit below it."""
    frame, level = sys._getframe(1), 1
    while frame is not None and frame.f_code.co_filename.startswith((_PACKAGE, _EQUINOX)):
        frame, level = frame.f_back, level + 1
    return level


def check_count(name, value, least):
    if value is not None:
        integer(value, name, least)


def check_positive(name, value, what):
    if value is not None and is_concrete(value):
        v = np.asarray(value)
        real(v.item() if v.ndim == 0 else v, f"{name} ({what})", minimum=0.0, strict=True)


def check_budget(budget):
    integer(budget, "budget (bytes of temporaries)", 2**20)
