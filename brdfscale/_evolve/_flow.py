"""The one evolve/select flow: arguments checked, the path chosen by the method object, then
resolved (:func:`select`) or evaluated (:func:`evolve`) by it.

Both functions share every step — :func:`check_arguments`, :func:`as_method`, the method's
:meth:`~AbstractMethod.choose` — and differ only in the last call: ``path.resolve(...)`` (the
discretisation verified for concrete values) or ``path.evaluate(...)`` (the lobe at the target
scale, resolved on the way when the values are concrete). Nothing here dispatches on the
method's type: each path's behaviour lives in its own module (``_closed_form.py``,
``_radial.py``, ``_grid.py``, ``_auto.py``).
"""

import numbers
import warnings
from typing import Literal

import jax.numpy as jnp
from jaxtyping import Array, Real

from .._errors import InvalidInputError, NoBRDFAtScaleError
from .._existence import advice, direction, GENERIC_ADVICE, NO_BRDF, regularisation_text
from .._validation import as_float_array, is_concrete, RealNumber
from ..lobes import AbstractLobe
from ..stats import AbstractSlopeDensity, require_density
from ._auto import Auto
from ._closed_form import ClosedForm
from ._grid import Grid
from ._method import AbstractMethod, MIN_TOL
from ._radial import Radial
from ._regularise import check_noise, needs_data, ranked, rule_name
from ._spectral import AbstractSpectralMethod


MethodName = Literal["auto", "closed_form", "radial", "grid"]
RegularisationName = Literal["auto", "gcv", "discrepancy", "l_curve"]

_NAMES = {"auto": Auto, "closed_form": ClosedForm, "radial": Radial, "grid": Grid}


def check_arguments(lobe, s_from, s_to, tol, regularisation, noise=None):
    """The checks :func:`brdfscale.evolve` and :func:`select` share: ``(tol, λ, rule, noise)`` —
    λ a float array (None when ``regularisation`` is None or a rule), the rule's name (None for a
    number; ``"auto"`` is the default rule) and the discrepancy rule's noise level."""
    if not isinstance(lobe, AbstractLobe):
        raise InvalidInputError(f"lobe must be a brdfscale.lobes lobe; got {type(lobe).__name__}.")
    for name, s in (("s_from", s_from), ("s_to", s_to)):
        require_density(
            s,
            name,
            use="Use it through brdfscale.plus.NearlySpecular(a, [c_0, …], x0, ...) "
            "(a δ + Σ c_n h_n + w s_smooth, mass 1).",
        )
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not MIN_TOL <= float(tol) < 1:
        raise InvalidInputError(
            f"tol must be a number in [{MIN_TOL:g}, 1) (an error relative to the lobe's peak; below "
            f"{MIN_TOL:g} float64 rounding in the evaluation exceeds it); got {tol!r}."
        )
    rule = rule_name(regularisation)
    noise = check_noise(rule, noise)
    if rule is not None or regularisation is None:
        return float(tol), None, rule, noise
    lam = as_float_array(regularisation, "regularisation")
    if lam.ndim != 0:
        raise InvalidInputError(f"regularisation must be one number λ ≥ 0 (or a rule's name); got shape {lam.shape}.")
    if is_concrete(lam) and float(lam) < 0:
        raise InvalidInputError(f"regularisation must be ≥ 0; got {float(lam)}.")
    return float(tol), lam, rule, noise


def as_method(method, size=None, extent=None) -> AbstractMethod:
    """A method object from a method or its name (``size``/``extent``: the string API's
    explicit discretisation, applied to whichever spectral path is taken)."""
    if isinstance(method, AbstractMethod):
        if size is not None or extent is not None:
            raise InvalidInputError(
                "size= and extent= go with a method name; with a method object put them in it: "
                "Radial(nodes=...) or Grid(size=..., extent=...)."
            )
        return method
    if not isinstance(method, str) or method not in _NAMES:
        raise InvalidInputError(
            f"method must be 'auto', 'closed_form', 'radial' or 'grid', or a method object (brdfscale.Auto(), "
            f"ClosedForm(), Radial(...), Grid(...)); got {method!r}."
        )
    return _NAMES[method]()


def evolve(
    lobe: AbstractLobe,
    s_from: AbstractSlopeDensity,
    s_to: AbstractSlopeDensity,
    method: AbstractMethod | MethodName = "auto",
    *,
    regularisation: RealNumber | Real[Array, ""] | RegularisationName | None = None,  # λ may be traced
    noise=None,
    tol: RealNumber = 1e-10,
    size: int | None = None,
    extent: float | None = None,
    check: bool = True,
) -> AbstractLobe:
    """Evolve a lobe measured at scale μ0 to scale μ (seed Eq. 4.4, docs/conventions.md §2).

    With the facet-slope densities ``s_from = s(·, μ0)`` and ``s_to = s(·, μ)`` the lobe
    transform evolves as

        G(W, μ) = G(W, μ0) · S(W, μ0) / S(W, μ),

    which is the seed's ``R(W, μ) = R(W, μ0) Q(W, μ0)/Q(W, μ)`` with ``Q(W) = S(−W)`` (the
    seed's q is the reflection of s). Going coarser (μ > μ0, ``s_to`` narrower) is a stable
    blur; going finer is a deconvolution. The amplitude is unchanged (energy is conserved).

    Args:
        lobe: the lobe at μ0 (:mod:`brdfscale.lobes`).
        s_from, s_to: facet-slope statistics at μ0 and μ (:mod:`brdfscale.stats`), e.g.
            ``law.at(mu0)`` and ``law.at(mu)`` of a scale law. ``s_to = Delta()`` is μ = ∞.
        method: a method object — :class:`brdfscale.ClosedForm` (Gaussian/δ/mixture algebra:
            exact), :class:`brdfscale.Radial` (Hankel quadrature; everything radially
            symmetric), :class:`brdfscale.Grid` (2D FFT; general), :class:`brdfscale.Auto`
            (the first that applies) — or its name ``"closed_form"``, ``"radial"``, ``"grid"``,
            ``"auto"``. For concrete values the spectral paths are resolved here
            (:func:`brdfscale.select`); under ``jax.jit``/``grad``/``vmap`` pass a resolved
            method (from ``select`` outside the transformation) or an explicit size — an
            unresolved spectral path raises :class:`brdfscale.UnresolvedMethodError`
            instead of guessing a size.
        regularisation: the Tikhonov λ ≥ 0 of the division, ``1/S_to → S_to*/(|S_to|² + λ²)``
            (the Tikhonov solution of ``g_from ∗ s_from = g_to ∗ s_to``), or a rule that chooses
            λ from a tabulated lobe (``lobes.Tabulated``; module ``brdfscale._evolve._regularise``):

            * ``"auto"`` — generalised cross-validation (``"gcv"``): minimises
              ``Σ|(1 − f)V|²/(Σ(1 − f))²`` over the table's own DFT frequencies, with the filter
              factors ``f = |S_to|²/(|S_to|² + λ²)`` and ``V`` the transform of the node values.
              Needs no noise level. In the stability study (docs/results.md) its error stayed
              within 1.2× of the best fixed λ chosen in hindsight at every noise level and case;
            * ``"discrepancy"`` — the largest λ whose residual does not exceed the expected noise
              (Morozov); needs ``noise=σ`` (per node value, one number or an array of the table's
              shape). Erratic where the residual is flat in λ (study: up to ×8e4 off);
            * ``"l_curve"`` — the corner of the L-curve (study: up to ×38 off with disk statistics).

            A lobe that is not tabulated is exact and every rule gives λ = 0 (Eq. 4.4 itself), as
            when nothing is divided (``s_to`` a point mass); only the lobe's noise is modelled
            (tabulated statistics are taken as exact). The choice needs concrete values: under
            ``jax.jit``/``grad``/``vmap`` a rule raises :class:`brdfscale.UnresolvedMethodError` —
            choose outside, ``m = select(lobe, s_from, s_to, regularisation="auto")``, and pass
            ``method=m``, which carries λ (``m.regularisation``, reported by ``m.explain()``).
            On measured data a lobe need not exist at the rule's λ (even going coarser: measured
            statistics do not nest exactly), so with concrete values every rule checks existence
            and, where its λ fails, takes the first of the search candidates (2 per decade, best
            GCV score first) for which the lobe exists (:func:`searched`; ``explain()`` names the
            λ refused); NoBRDFAtScaleError when none does.
            ``None`` (default): the λ a resolved method carries, else 0. Leave 0 for analytic
            inputs. The chosen λ is ``result.shape.regularisation``. With noisy input the evolved
            lobe has ripples of about the noise level: the sign check then needs a ``tol`` of
            that order (or ``check=False``).
        noise: the standard deviation of the table's node values, for ``"discrepancy"`` only.
        tol: error target relative to the lobe's peak, in [1e-14, 1); sets the frequency
            cut-off (beyond it |G| < tol and its k-weighted tail < tol of the whole), the
            radial rule's nodes and the grid extent of the spectral paths.
        size: with a method name: Gauss–Legendre nodes (radial) or grid side (grid), as
            ``Radial(nodes=size)`` / ``Grid(size=size)``. Default: chosen from ``tol`` for
            concrete parameters (capped at 16384 / 1024); required under tracing.
            When a capped grid cannot meet ``tol`` (heavy-tailed statistics such as GGX
            need grids of extent ∝ tol^{−1/4}), the grid path relaxes the target by decades,
            warns (:class:`brdfscale.ToleranceRelaxedWarning`) and records the tolerance it
            honours in ``result.shape.tol`` and the tol asked in ``explain()``.
        extent: with a method name: half-width of the grid path's slope grid (a number).
            Default: the radius beyond which the lobe stays below ``tol/2`` relative to its
            peak; offsets outside the grid evaluate to 0 (never a periodic image).
        check: verify that a BRDF exists at μ (see Raises). ``check=False`` leaves out the
            run-time check (an ``equinox.error_if`` conditional, which costs a measurable
            share of a small model's evaluation inside an optimiser's loop: ``python -m
            experiments.bench_fit``); a closed form built from concrete values is still
            checked when it is built. Only for callers that have established existence
            otherwise, e.g. evolving towards coarser scales with a scale law whose slope
            variances decrease with μ; where no BRDF exists the result is then undefined
            (NaN for the closed form).

    Returns:
        The lobe at μ. Closed forms return a lobe whose shape is a :mod:`brdfscale.stats`
        family; the spectral paths return a lobe whose shape evaluates the exact transform
        and inverts it only where asked: ``.density(u)`` at any number of query offsets (in
        blocks within the method's memory budget), or ``.shape.on_grid()`` on the FFT grid
        (grid path). ``result.shape.discretisation`` is the resolved method
        (``.explain()``), ``result.shape.tol`` the error it honours relative to the peak.

    Raises:
        NoBRDFAtScaleError: no non-negative lobe exists at μ (e.g. a Gaussian lobe would
            need a negative variance, the quotient's transform exceeds 1 in modulus, or the
            evolved values fall below −tol of the peak). For concrete values the message names
            the direction of the evolution (finer or coarser, from the two statistics:
            :func:`brdfscale._existence.direction`) and the regularisation in force. Inside a
            user's ``jax.jit`` the check runs with the program (``equinox.error_if``) and reaches the user as equinox's
            runtime error carrying the same message (``brdfscale._existence``).
        UnresolvedMethodError: traced parameters and a spectral path without a size, or a
            regularisation rule with a traced tabulated lobe and no λ carried by ``method``.
        MethodNotApplicableError: a forced ``method`` cannot handle the inputs.
        InvalidInputError: wrong argument types or values.

    Everything is differentiable in all continuous parameters (and in μ through a scale
    law), works under ``jax.jit``/``jax.vmap`` and in float32 or float64.
    """
    tol, lam, rule, noise = check_arguments(lobe, s_from, s_to, tol, regularisation, noise)
    named = isinstance(method, str)
    path = as_method(method, None if named else size, None if named else extent).choose(lobe, s_from, s_to)
    if named:
        path = path.with_sizes(size, extent)
    with _in_context(path, lam, s_from, s_to):
        if _searches(path, lobe, s_from, s_to, rule, noise):
            path = searched(path, lobe, s_from, s_to, tol, rule, noise, check)
        return path.evaluate(lobe, s_from, s_to, tol=tol, regularisation=lam, rule=rule, noise=noise, check=check)


def select(
    lobe: AbstractLobe,
    s_from: AbstractSlopeDensity,
    s_to: AbstractSlopeDensity,
    *,
    tol: RealNumber = 1e-10,
    method: AbstractMethod | str = "auto",
    regularisation: float | str = 0.0,
    noise=None,
    check: bool = True,
) -> AbstractMethod:
    """The resolved discretisation with which :func:`brdfscale.evolve` meets ``tol``.

    Decides, from the concrete values given, the path (closed form, radial or grid — the
    first that applies, or the one forced by ``method``) and everything it needs: the
    Gauss–Legendre nodes, the cut-off K and a verified table of radii (radial); the grid side,
    half-width and a verified oversampling (grid); and checks that a BRDF exists for these
    values (the verifications: the docstrings of :mod:`._radial` and :mod:`._grid`). The
    result is a static object: pass it as ``evolve(..., method=result)`` inside
    ``jax.jit``/``grad``/``vmap``, where it is used as it is. ``result.explain()`` says what it
    chose; ``result.tol`` is the error relative to the lobe's peak it honours (looser than asked
    only when a capped grid cannot do better).

    ``regularisation``: the Tikhonov λ of the division as in :func:`brdfscale.evolve` — a
    number, or a rule (``"auto"``, ``"gcv"``, ``"discrepancy"`` with ``noise=σ``, ``"l_curve"``)
    that chooses λ from the concrete values here. A spectral result carries the λ (a rule's
    choice, or a nonzero number) and the discretisation verified for it:
    ``result.regularisation``, reported by ``result.explain()``; ``evolve(..., method=result)``
    uses it, under ``jax.jit`` too.

    Raises:
        UnresolvedMethodError: the values are traced (call it outside the transformation).
        NoBRDFAtScaleError: no non-negative lobe exists for these values.
        MethodNotApplicableError: a forced method does not apply.
        InvalidInputError: bad arguments.
    """
    tol, lam, rule, noise = check_arguments(lobe, s_from, s_to, tol, regularisation, noise)
    path = as_method(method).choose(lobe, s_from, s_to)
    with _in_context(path, lam, s_from, s_to):
        if _searches(path, lobe, s_from, s_to, rule, noise):
            return searched(path, lobe, s_from, s_to, tol, rule, noise, check)
        return path.resolve(lobe, s_from, s_to, tol=tol, regularisation=lam, rule=rule, noise=noise, check=check)


def _searches(path, lobe, s_from, s_to, rule, noise) -> bool:
    """Whether a rule's λ is chosen here by :func:`searched`: a spectral path, a tabulated lobe
    and a division, concrete values, and no λ of that rule carried by the method already."""
    if rule is None or not isinstance(path, AbstractSpectralMethod) or not needs_data(lobe, s_to):
        return False
    if path.carried()[1] == rule:
        return False
    return is_concrete((lobe, s_from, s_to, noise))


def searched(path, lobe, s_from, s_to, tol, rule, noise, check):
    """``path`` resolved with the first λ of :func:`._regularise.ranked` (the rule's choice, then
    the search candidates by GCV score) for which the evolved lobe exists — the existence check of
    ``resolve`` (:mod:`brdfscale._existence`) passes and the grid resolves the lobe at all. It
    carries λ, the rule and how λ was found (``explain()``). The warnings of the λ taken are
    re-issued, those of the λ refused are not. NoBRDFAtScaleError when no candidate gives a lobe,
    naming the direction and the λ tried."""
    refused: list[tuple[float, str]] = []
    for lam, how in ranked(lobe, s_from, s_to, rule, noise):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                resolved = path.resolve(
                    lobe, s_from, s_to, tol=tol, regularisation=jnp.asarray(lam), rule=None, noise=None, check=check
                )
            except (NoBRDFAtScaleError, InvalidInputError) as err:
                refused.append((lam, str(err).split(". ", 1)[0].replace(NO_BRDF + ": ", "")))
                continue
        for warning in caught:
            warnings.warn(warning.message, stacklevel=4)
        if refused:
            first, reason = refused[0]
            how = (
                f"{how}, the first of the λ tried for which the lobe exists: the rule's own λ = {first:.3g} was "
                f"refused ({reason})" + (f", and {len(refused) - 1} more" if len(refused) > 1 else "")
            )
        return resolved.carrying(jnp.asarray(lam), rule, how)
    tried = ", ".join(f"{lam:.3g}" for lam, _ in refused)
    raise NoBRDFAtScaleError(
        advice(
            NO_BRDF + f": no λ tried by regularisation={rule!r} gives a lobe that exists (first refusal: "
            f"{refused[0][1]})." + GENERIC_ADVICE,
            direction(s_from, s_to),
            f"every λ in {{{tried}}} tried",
        )
    )


class _in_context:
    """Re-raise a concrete :class:`NoBRDFAtScaleError` with the advice for the evolution's
    direction and the regularisation in force (:func:`brdfscale._existence.advice`)."""

    def __init__(self, path, lam, s_from, s_to):
        self.path, self.lam, self.s_from, self.s_to = path, lam, s_from, s_to

    def __enter__(self):
        return self

    def __exit__(self, kind, err, tb):
        if not isinstance(err, NoBRDFAtScaleError) or GENERIC_ADVICE not in str(err):
            return False
        lam, note = self.lam, "given"
        if lam is None and isinstance(self.path, AbstractSpectralMethod):
            lam, note = self.path.carried()[0], self.path.regularisation_note
        raise NoBRDFAtScaleError(
            advice(str(err), direction(self.s_from, self.s_to), regularisation_text(lam, note))
        ) from None
