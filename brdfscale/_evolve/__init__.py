"""The isotropic (slope-space) evolution operator, seed Eq. 4.4."""

import numbers
import warnings
from typing import Literal

from .._errors import InvalidInputError, MethodNotApplicableError
from .._validation import as_float_array, is_concrete
from ..lobes import AbstractLobe, Lobe
from ..stats import AbstractSlopeDensity
from ._algebra import convolve, deconvolve
from ._spectral import EvolvedDensity, choose_size

Method = Literal["auto", "closed_form", "radial", "grid"]

_DEFAULT_SIZE = {"radial": 256, "grid": 256}
_MAX_SIZE = {"radial": 4096, "grid": 1024}
_MIN_TOL = 1e-14


def evolve(
    lobe: AbstractLobe,
    s_from: AbstractSlopeDensity,
    s_to: AbstractSlopeDensity,
    method: Method = "auto",
    *,
    regularisation: float = 0.0,
    tol: float = 1e-10,
    size: int | None = None,
    extent: float | None = None,
    check: bool = True,
) -> AbstractLobe:
    """Evolve a lobe measured at scale μ0 to scale μ (seed Eq. 4.4, DESIGN §2).

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
        method: ``"closed_form"`` (Gaussian/δ/mixture algebra: exact), ``"radial"`` (Hankel
            quadrature; everything radially symmetric), ``"grid"`` (2D FFT; general), or
            ``"auto"``: the first of these that applies.
        regularisation: Tikhonov λ ≥ 0 of the division, ``1/S → S*/(|S|² + λ²)``. Leave 0
            for analytic inputs; for tabulated or noisy lobes use about the relative noise
            level of ``G(W, μ0)`` (Wiener's choice λ² = noise power / signal power).
        tol: error target relative to the lobe's peak, in [1e-14, 1); sets the frequency
            cut-off (beyond it |G| < tol and its k-weighted tail < tol of the whole), the
            radial rule's nodes and the grid extent of the spectral paths.
        size: Gauss–Legendre nodes (radial) or grid side (grid). Default: chosen from
            ``tol`` when the parameters are concrete (capped at 4096 / 1024), else 256.
            When a capped grid cannot meet ``tol`` (heavy-tailed statistics such as GGX
            need grids of extent ∝ tol^{−1/4}), the grid path relaxes the target by decades
            and records the tolerance it honours in ``result.shape.tol``.
        extent: half-width of the grid path's slope grid. Default: the radius beyond which
            the lobe stays below ``tol`` relative to its peak (aliasing below ``tol``).
        check: verify that a BRDF exists at μ (see Raises). ``check=False`` leaves out the
            run-time check (an ``equinox.error_if`` conditional, which costs a measurable
            share of a small model's evaluation inside an optimiser's loop: ``python
            experiments/bench_fit.py``); a closed form built from concrete values is still
            checked when it is built. Only for callers that have established existence
            otherwise, e.g. evolving towards coarser scales with a scale law whose slope
            variances decrease with μ; where no BRDF exists the result is then undefined
            (NaN for the closed form).

    Returns:
        The lobe at μ. Closed forms return a lobe whose shape is a :mod:`brdfscale.stats`
        family; the spectral paths return a lobe whose shape evaluates the exact transform
        and inverts it only where asked: ``.density(u)`` at query offsets, or
        ``.shape.on_grid()`` on the FFT grid (grid path).

    Raises:
        NoBRDFAtScaleError: no non-negative lobe exists at μ (e.g. a Gaussian lobe would
            need a negative variance, or the quotient's transform exceeds 1 in modulus).
            Under ``jax.jit`` this is raised at run time through ``equinox.error_if``.
        MethodNotApplicableError: a forced ``method`` cannot handle the inputs.
        InvalidInputError: wrong argument types or values.

    Everything is differentiable in all continuous parameters (and in μ through a scale
    law), works under ``jax.jit``/``jax.vmap`` and in float32 or float64.
    """
    if not isinstance(lobe, AbstractLobe):
        raise InvalidInputError(f"lobe must be a brdfscale.lobes lobe; got {type(lobe).__name__}.")
    for name, s in (("s_from", s_from), ("s_to", s_to)):
        if not isinstance(s, AbstractSlopeDensity):
            raise InvalidInputError(f"{name} must be a brdfscale.stats density; got {type(s).__name__}.")
        if not getattr(s, "is_probability_density", True):
            raise InvalidInputError(
                f"{name} must be a probability density of facet slopes (mass 1); got {type(s).__name__}, "
                "a generalised function of mass 0 (a plus-distribution h_n). Use it through "
                "brdfscale.plus.NearlySpecular(a, [c_0, …], x0, ...) (a δ + Σ c_n h_n + w s_smooth, mass 1).")
    if method not in ("auto", "closed_form", "radial", "grid"):
        raise InvalidInputError(f"method must be 'auto', 'closed_form', 'radial' or 'grid'; got {method!r}.")
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not _MIN_TOL <= tol < 1:
        raise InvalidInputError(
            f"tol must be a number in [{_MIN_TOL:g}, 1) (an error relative to the lobe's peak; below "
            f"{_MIN_TOL:g} float64 rounding in the evaluation exceeds it); got {tol!r}.")
    tol = float(tol)
    lam = as_float_array(regularisation, "regularisation")
    if is_concrete(lam) and float(lam) < 0:
        raise InvalidInputError(f"regularisation must be ≥ 0; got {float(lam)}.")

    if method in ("auto", "closed_form"):
        numerator = convolve(lobe.shape, s_from)
        shape = deconvolve(numerator, s_to, check) if numerator is not None else None
        if shape is not None:
            return Lobe(shape, lobe.amplitude)
        if method == "closed_form":
            raise MethodNotApplicableError(
                f"no closed form for a {type(lobe.shape).__name__} lobe with {type(s_from).__name__} → "
                f"{type(s_to).__name__} statistics; closed forms exist for Gaussian/Beckmann lobes and "
                "statistics (and mixtures of them), δ (Mirror) lobes, and δ statistics. Use method='grid'."
            )

    isotropic = lobe.shape.isotropic and s_from.isotropic and s_to.isotropic
    if method == "radial" and not isotropic:
        raise MethodNotApplicableError(
            "method='radial' needs a radially symmetric lobe and statistics (isotropic, centred); "
            "use method='grid' for anisotropic, shifted, skewed or tabulated inputs."
        )
    path = "radial" if (method == "radial" or (method == "auto" and isotropic)) else "grid"
    if size is not None and (int(size) != size or size < 8):
        raise InvalidInputError(f"size must be an integer ≥ 8; got {size!r}.")
    if extent is not None:
        extent = as_float_array(extent, "extent")
        if is_concrete(extent) and not float(extent) > 0:
            raise InvalidInputError(f"extent must be a positive slope half-width; got {float(extent)}.")
    shape = EvolvedDensity(lobe.shape, s_from, s_to, lam, path, size or _DEFAULT_SIZE[path], tol, extent, check)
    if is_concrete(shape) and (size is None or path == "grid"):  # an explicit radial size needs no check
        try:
            needed, achievable = choose_size(shape, path, max(_MAX_SIZE[path], size or 0))
        except InvalidInputError as err:  # no automatic size resolves it: the caller's own size stands
            if size is None:
                raise
            warnings.warn(f"{err} Evaluating with size={size} as given: expect errors well above tol.", stacklevel=2)
            needed = size
        if size is None:
            shape = EvolvedDensity(lobe.shape, s_from, s_to, lam, path, needed, achievable, extent, check)
        elif path == "grid" and size < needed:
            warnings.warn(
                f"size={size} is below the {needed} nodes per side that tol={tol:g} needs on this "
                f"grid; expect errors well above tol (leave size=None to choose it).",
                stacklevel=2,
            )
    return Lobe(shape, lobe.amplitude)
