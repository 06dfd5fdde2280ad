"""The isotropic (slope-space) evolution operator, seed Eq. 4.4, and its paths as objects."""

from typing import Literal

from .._errors import MethodNotApplicableError, UnresolvedMethodError
from .._validation import is_concrete
from ..lobes import AbstractLobe, Lobe
from ..stats import AbstractSlopeDensity
from ._algebra import convolve, deconvolve, has_closed_form
from ._methods import (AbstractMethod, Auto, ClosedForm, Grid, Radial, RadialTable, as_method, carried, carrying,
                       with_sizes)
from ._regularise import CANDIDATES as REGULARISATION_CANDIDATES, DEFAULT_RULE, RULES, choose as choose_regularisation
from ._select import (MAX_GRID, MAX_RADIAL_NODES, check_arguments, regularised, resolve, select, spectral_path,
                      unresolved)
from ._spectral import CORE_TOL, EvolvedDensity, cutoff, grid_size, probe_checks, radial_nodes, radial_reach

MethodName = Literal["auto", "closed_form", "radial", "grid"]
RegularisationName = Literal["auto", "gcv", "discrepancy", "l_curve"]

__all__ = ["evolve", "select", "AbstractMethod", "Auto", "ClosedForm", "Radial", "Grid", "RadialTable",
           "UnresolvedMethodError", "EvolvedDensity", "cutoff", "radial_nodes", "radial_reach", "grid_size",
           "probe_checks", "has_closed_form", "CORE_TOL", "MAX_GRID", "MAX_RADIAL_NODES", "RULES", "DEFAULT_RULE",
           "REGULARISATION_CANDIDATES", "choose_regularisation"]


def evolve(
    lobe: AbstractLobe,
    s_from: AbstractSlopeDensity,
    s_to: AbstractSlopeDensity,
    method: AbstractMethod | MethodName = "auto",
    *,
    regularisation: float | RegularisationName | None = None,
    noise=None,
    tol: float = 1e-10,
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
            need grids of extent ∝ tol^{−1/4}), the grid path relaxes the target by decades
            and records the tolerance it honours in ``result.shape.tol``.
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
            evolved values fall below −tol of the peak). Inside a user's ``jax.jit`` the check
            runs with the program (``equinox.error_if``) and reaches the user as equinox's
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
    method = as_method(method, None if named else size, None if named else extent)

    if isinstance(method, (Auto, ClosedForm)):
        numerator = convolve(lobe.shape, s_from)
        shape = deconvolve(numerator, s_to, check) if numerator is not None else None
        if shape is not None:
            return Lobe(shape, lobe.amplitude)
        if isinstance(method, ClosedForm):
            raise MethodNotApplicableError(
                f"no closed form for a {type(lobe.shape).__name__} lobe with {type(s_from).__name__} → "
                f"{type(s_to).__name__} statistics; closed forms exist for Gaussian/Beckmann lobes and "
                "statistics (and mixtures of them), δ (Mirror) lobes, and δ statistics. Use method='grid'."
            )
    # Auto cannot pick the closed form here: has_closed_form holds exactly where the algebra above answers
    method = spectral_path(method, lobe, s_from, s_to)
    if named:
        method = with_sizes(method, size, extent)
    lam, method = regularised(method, lobe, s_from, s_to, lam, rule, noise)
    shape = EvolvedDensity(lobe.shape, s_from, s_to, lam, method, tol if method.tol is None else method.tol, check)
    if method.tol is None and is_concrete(shape):
        chosen = carried(method)
        method = resolve(shape, method)
        if chosen[0] is not None:
            method = carrying(method, chosen[0], chosen[1], shape.discretisation.regularisation_note)
        shape = shape.with_discretisation(method, method.tol)
    elif not method.resolved:
        raise unresolved(method)
    return Lobe(shape, lobe.amplitude)

