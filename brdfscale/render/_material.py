"""A material as tables: the evolved lobe on a log-μ ladder, computed once in JAX (issue 33 item 1).

A brdfscale material is a base lobe at the scale μ0 plus the statistics of its facets across scales. The renderer
needs the lobe at the observation scale μ of every interaction; calling JAX per ray would be far too slow, so the
lobe is evolved here (seed Eq. 4.4, :func:`brdfscale.evolve`) to every scale of a ladder ``μ_0 < … < μ_{L−1}``
evenly spaced in ln μ and tabulated on one grid of half-vector slope offsets — an :class:`brdfscale.exr.LobeTable`,
the same object an evolved table read from EXR is — and the Mitsuba plugin (:mod:`._plugin`) interpolates it
bilinearly in the offset and linearly in ln μ.

Statistics accepted (:func:`as_scale_law`): anything with ``.at(μ)`` returning a :mod:`brdfscale.stats` density (the
scale laws, :class:`brdfscale.stats.MeasuredScaleLaw`); a :class:`fitting.FitResult` with its covariance differences
``ΔΣ(μ0, μ_k)`` (fit.json's ``covariance_differences``); a :class:`brdfscale.exr.LobeTable` (already tabulated).
"""

import math

import jax.numpy as jnp
import numpy as np

from .. import lobes, stats
from .._choices import FORMS
from .._errors import InvalidInputError
from .._evolve import AbstractMethod, evolve, MethodName
from .._validation import integer, real
from ..exr import LobeTable
from ..lobes import AbstractLobe
from ._spline import GHOSTS, on_grid, prefilter, runs, runs_coefficients


ACCEPTED = (
    "a scale law (anything with .at(μ) returning a brdfscale.stats density: stats.GaussianSurface, "
    "stats.ScaledFamily, stats.MeasuredScaleLaw, …), a fitting.FitResult with covariance_differences, "
    "or an evolved brdfscale.exr.LobeTable (e.g. exr.read_lobe_table(path))"
)

DEFAULT_LEVELS = 9
"""Scales on the default ladder: ``μ0 · 2^k``, k = 0 … 8 (or the measured range of a MeasuredScaleLaw)."""

SUPPORT_TOL = 1e-4
"""The lobe tables reach where every level's lobe has fallen below this fraction of its peak (``support_radius``)."""

RELEVANT = 1e-3
"""Interpolation errors are measured where the exact lobe exceeds this fraction of its peak (:func:`refine_ladder`)."""

MAX_LEVELS = 128
"""The most scales :func:`refine_ladder` puts on a tabulated ladder (it refuses to go further)."""

MAX_CLOSED_LEVELS = 4096
"""The most scales :func:`refine_ladder` puts on a closed-form ladder (six numbers per scale)."""

MAX_NODES = 1024
"""The most slope nodes per axis :func:`refine_grid` chooses (it refuses to go further)."""

MAX_SPLINE_LEVELS = 257
"""The most scales :func:`refine_uniform_ladder` puts on a spline ladder (it refuses to go further)."""

RUN_INTERVALS = 8
"""A spline run refined to this many intervals or more is cut in two runs (:func:`refine_runs`)."""

SPLINE_PAD = 2
"""Zero nodes around a spline table's slope grid (the B-spline reaches two nodes: beyond them the lobe is 0)."""


def grid_error(lobe, extent: float, size: int) -> float:
    """The largest relative error of bilinear interpolation on ``size²`` nodes over ``[−extent, extent]²``: at every
    cell centre (where a tent sum's error peaks), the mean of the cell's four corners against the lobe's density,
    where it exceeds :data:`RELEVANT` of its largest value."""
    u = np.linspace(-extent, extent, size)
    c = 0.5 * (u[:-1] + u[1:])
    nodes = np.asarray(lobe.density(jnp.asarray(np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)))).reshape(size, size)
    exact = np.asarray(lobe.density(jnp.asarray(np.stack(np.meshgrid(c, c), -1).reshape(-1, 2))))
    exact = exact.reshape(size - 1, size - 1)
    corners = 0.25 * (nodes[:-1, :-1] + nodes[1:, :-1] + nodes[:-1, 1:] + nodes[1:, 1:])
    big = exact > RELEVANT * max(exact.max(), nodes.max())
    return float(np.max(np.abs(corners[big] / exact[big] - 1))) if big.any() else 0.0


def spline_grid_error(lobe, extent: float, size: int) -> float:
    """The largest relative error of the cubic B-spline (:mod:`._spline`) through the lobe's density on ``size²``
    nodes over ``[−extent, extent]²`` bordered by :data:`SPLINE_PAD` rings of zero nodes — what the spline form
    renders — at every cell centre, where the lobe exceeds :data:`RELEVANT` of its largest value."""
    h = 2 * extent / (size - 1)
    u = -extent + h * np.arange(-SPLINE_PAD, size + SPLINE_PAD)
    nodes = np.array(lobe.density(jnp.asarray(np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)))).reshape(len(u), -1)
    ring = np.zeros(len(u), bool)
    ring[:SPLINE_PAD] = ring[-SPLINE_PAD:] = True
    nodes[ring] = 0.0
    nodes[:, ring] = 0.0
    x = np.arange(len(u) - 1) + 0.5
    estimate = on_grid(prefilter(nodes), [x, x])
    c = u[:-1] + 0.5 * h
    exact = np.asarray(lobe.density(jnp.asarray(np.stack(np.meshgrid(c, c), -1).reshape(-1, 2)))).reshape(len(c), -1)
    big = exact > RELEVANT * max(exact.max(), nodes.max())
    return float(np.max(np.abs(estimate[big] / exact[big] - 1))) if big.any() else 0.0


def refine_grid(evolved, extent: float, size: int, tolerance: float, measure=grid_error) -> int:
    """The smallest ``size, 2·size − 1, 4·size − 3, …`` (nested grids) whose interpolation of every lobe is within
    ``tolerance`` by ``measure`` (:func:`grid_error`: bilinear, the table form's; :func:`spline_grid_error`: the
    spline form's); InvalidInputError beyond :data:`MAX_NODES` nodes per axis."""
    for lobe in sorted(evolved, key=lambda lobe: float(jnp.max(lobe.shape.support_radius(SUPPORT_TOL)))):
        while (error := measure(lobe, extent, size)) > tolerance:
            size = 2 * size - 1
            if size > MAX_NODES:
                raise InvalidInputError(
                    f"tolerance = {tolerance:g} needs more than {MAX_NODES} slope nodes per axis (interpolation "
                    f"error {error:.2g} on {(size + 1) // 2}); give a larger tolerance or a smaller extent."
                )
    return size


def gaussian_parameters(evolved) -> np.ndarray | None:
    """``(L, 6)``: ``[A, c_x, c_y, Σ_xx, Σ_xy, Σ_yy]`` of every lobe, where each is ``A`` times one (unbatched)
    :class:`brdfscale.stats.Gaussian` of mean c and covariance Σ — what :func:`brdfscale.evolve` returns in closed
    form for Gaussian/Beckmann lobes and Gaussian statistics (covariances add, seed Eq. 4.4) — else None."""
    rows = []
    for lobe in evolved:
        shape = lobe.shape
        if type(shape) is not stats.Gaussian or np.shape(shape.cov) != (2, 2):
            return None
        cov = np.asarray(shape.cov, float)
        mean = np.zeros(2) if shape.mean is None else np.asarray(shape.mean, float).reshape(2)
        rows.append([float(lobe.amplitude), mean[0], mean[1], cov[0, 0], 0.5 * (cov[0, 1] + cov[1, 0]), cov[1, 1]])
    return np.asarray(rows, float)


def gaussian_lobe(row) -> lobes.Lobe:
    """The lobe of one row of :func:`gaussian_parameters`."""
    a, cx, cy, sxx, sxy, syy = (float(x) for x in row)
    return lobes.Lobe(stats.Gaussian(cov=[[sxx, sxy], [sxy, syy]], mean=[cx, cy]), a)


class TableForm:
    """The lobe tabulated on a slope grid per scale, interpolated bilinearly in the offset and linearly in ln μ
    (what :mod:`._plugin` renders from a :class:`brdfscale.exr.LobeTable`): between two scales a *mixture* of their
    lobes."""

    name = "table"
    measure = staticmethod(grid_error)
    """The slope grid's interpolation error (:func:`refine_grid`)."""

    @property
    def max_levels(self) -> int:
        return MAX_LEVELS

    def refine(self, base_lobe, law, mu0, ladder, evolved, tolerance, method):
        """The ladder refined until its interpolation is within ``tolerance`` (:func:`refine_ladder`), and no breaks."""
        return (*refine_ladder(base_lobe, law, mu0, ladder, evolved, tolerance, method, form=self), None)

    def between(self, lower, upper):
        """What the plugin renders at the geometric midpoint of two scales: the mean of their lobes."""
        return lambda u: 0.5 * (lower.density(u) + upper.density(u))


class GaussianForm:
    """The closed form of Gaussian lobes: per scale the amplitude, mean and covariance (:func:`gaussian_parameters`),
    interpolated linearly in ln μ and evaluated exactly (Gaussian density and Smith Λ in closed form) by
    :mod:`._plugin`. Exact between two scales where the law's covariance is linear in ln μ there (a
    :class:`brdfscale.stats.MeasuredScaleLaw` between its measured scales)."""

    name = "closed"
    measure = None

    @property
    def max_levels(self) -> int:
        return MAX_CLOSED_LEVELS

    refine = TableForm.refine

    def between(self, lower, upper):
        """The Gaussian lobe of the mean parameters of two scales' lobes."""
        rows = gaussian_parameters([lower, upper])
        assert rows is not None  # the closed form is chosen only for Gaussian lobes
        return gaussian_lobe(rows.mean(axis=0)).density


class SplineForm:
    """The lobe tabulated on a slope grid per scale, interpolated by a tricubic B-spline through the values
    (:mod:`._spline`; Dr.Jit's ``eval_cubic``), its G₁ tables likewise: the error falls as the fourth power of the
    steps (the table form's as the square), so far fewer scales and nodes reach a tolerance. Along ln μ the ladder is
    cut into runs of equal steps (:func:`spline_breaks`: also at a measured law's own scales, where its Σ has kinks),
    each interpolated by its own spline with cubically extrapolated ends; the refinement halves a run's steps
    (:func:`refine_runs`)."""

    name = "spline"
    measure = staticmethod(spline_grid_error)

    @property
    def max_levels(self) -> int:
        return MAX_SPLINE_LEVELS

    def refine(self, base_lobe, law, mu0, ladder, evolved, tolerance, method):
        """The ladder refined until its splines are within ``tolerance``, and its breaks (:func:`refine_runs`)."""
        return refine_runs(base_lobe, law, mu0, ladder, evolved, tolerance, method)


TABLE, CLOSED, SPLINE = TableForm(), GaussianForm(), SplineForm()
_BY_NAME = {form.name: form for form in (TABLE, CLOSED, SPLINE)}
"""The forms :func:`brdfscale.render.bsdf` renders a material in, by name (``form=``: the names and ``"auto"`` are
:data:`brdfscale.choices.FORMS`)."""


def choose_form(form: str, evolved) -> TableForm | GaussianForm | SplineForm:
    """The form ``form`` names for these evolved lobes (InvalidInputError naming the accepted ones); ``"auto"``:
    closed where every evolved lobe is Gaussian, else table."""
    if FORMS.check(form) == "auto":
        return _BY_NAME["closed" if gaussian_parameters(evolved) is not None else "table"]
    if form == "closed" and gaussian_parameters(evolved) is None:
        raise InvalidInputError(
            "form='closed' needs Gaussian evolved lobes (a Gaussian/Beckmann base lobe with Gaussian statistics: "
            "brdfscale.evolve's closed form); these are not — use form='table' or 'auto'."
        )
    return _BY_NAME[form]


def midpoint_error(lower, upper, middle, extent: float, form=None) -> float:
    """The largest relative error of the ladder's interpolation at the geometric midpoint of an interval: what the
    ``form`` renders there (:meth:`TableForm.between`: the mean of the lobes at its ends; :meth:`GaussianForm.between`:
    the Gaussian of their mean parameters) against ``middle``, the lobe evolved exactly to ``√(μ_a μ_b)``, on 65²
    offsets over the table's extent where ``middle`` exceeds :data:`RELEVANT` of its peak."""
    u = np.linspace(-extent, extent, 65)
    grid = jnp.asarray(np.stack(np.meshgrid(u, u), -1).reshape(-1, 2))
    estimate = np.asarray((form or TABLE).between(lower, upper)(grid))
    c = np.asarray(middle.density(grid))
    big = c > RELEVANT * c.max()
    return float(np.max(np.abs(estimate[big] / c[big] - 1)))


def refine_ladder(base_lobe, law, mu0: float, ladder, evolved, tolerance: float, method, extent=None, form=None):
    """Bisect (in ln μ) every interval of ``ladder`` whose midpoint error (:func:`midpoint_error` of the ``form``,
    default the table's) exceeds ``tolerance``, until none does; returns the refined ``(ladder, evolved)``.

    Linear interpolation in ln μ of two lobes of different widths is a mixture, not the lobe between them; its
    error falls as the square of the interval, and is largest where the lobe changes fastest (near μ0, where the
    law's ``Σ(μ0) − Σ(μ)`` grows fastest). The closed form interpolates the covariance instead, exact where the law
    is linear in ln μ. Raises InvalidInputError beyond :data:`MAX_LEVELS` scales."""
    s0 = law.at(mu0)
    form = form or TABLE
    if extent is None:
        extent = max(float(jnp.max(lobe.shape.support_radius(SUPPORT_TOL))) for lobe in evolved)
    mus, out = [float(ladder[0])], [evolved[0]]
    stack = [(float(a), float(b), la, lb) for a, b, la, lb in zip(ladder[:-1], ladder[1:], evolved[:-1], evolved[1:])]
    stack.reverse()
    while stack:
        a, b, la, lb = stack.pop()
        mid = math.sqrt(a * b)
        lm = evolve(base_lobe, s0, law.at(mid), method)
        if midpoint_error(la, lb, lm, extent, form) > tolerance:
            if len(mus) + len(stack) + 2 > form.max_levels:
                raise InvalidInputError(
                    f"tolerance = {tolerance:g} needs more than {form.max_levels} scales on the ladder "
                    f"(interval [{a:g}, {b:g}] still off); give a larger tolerance or a shorter ladder."
                )
            stack.append((mid, b, lm, lb))
            stack.append((a, mid, la, lm))
            continue
        mus.append(b)
        out.append(lb)
    return np.asarray(mus), out


def spline_breaks(ladder, law) -> list[int]:
    """Where the spline form's interpolation in ln μ restarts: the ends and breaks of the ladder's runs of equal
    ln-μ steps (:func:`brdfscale.render._spline.runs`), and every scale of the ladder that is one of the law's own
    (``law.mu``: a :class:`brdfscale.stats.MeasuredScaleLaw` is linear in ln μ between them, so the lobe has a kink
    there that one spline across it would smear over its neighbours)."""
    x = np.log(np.asarray(ladder, float))
    breaks = set(runs(x))
    own = getattr(law, "mu", None)
    if own is not None:
        own = np.log(np.asarray(own, float))
        breaks |= {k for k, v in enumerate(x) if np.any(np.abs(own - v) <= 1e-9 * max(1.0, abs(v)))}
    return sorted(breaks)


def spline_run_error(evolved, middles, extent: float) -> float:
    """The largest relative error of one run's spline in ln μ (:func:`brdfscale.render._spline.runs_coefficients`)
    through ``evolved`` (its lobes, equal ln-μ steps) at every interval's midpoint, against ``middles`` (the lobes
    evolved exactly to ``√(μ_k μ_{k+1})``), on 65² offsets over the table's extent where each middle lobe exceeds
    :data:`RELEVANT` of its peak."""
    u = np.linspace(-extent, extent, 65)
    grid = jnp.asarray(np.stack(np.meshgrid(u, u), -1).reshape(-1, 2))
    nodes = np.stack([np.asarray(lobe.density(grid)) for lobe in evolved])
    coefficients = runs_coefficients(nodes, [0, len(evolved) - 1])  # the offset axis: clamped, evaluated at nodes
    estimate = on_grid(coefficients, [GHOSTS + np.arange(len(evolved) - 1) + 0.5, np.arange(len(u) ** 2)])
    worst = 0.0
    for row, middle in zip(estimate, middles):
        c = np.asarray(middle.density(grid))
        big = c > RELEVANT * c.max()
        worst = max(worst, float(np.max(np.abs(row[big] / c[big] - 1))))
    return worst


def refine_runs(base_lobe, law, mu0: float, ladder, evolved, tolerance: float, method, extent=None):
    """Refine the runs of the ladder (:func:`spline_breaks`) until each one's spline is within ``tolerance`` of the
    lobe evolved exactly to every midpoint (:func:`spline_run_error`): a run that misses has its ln-μ steps halved
    (the midpoint lobes join the ladder), and one of :data:`RUN_INTERVALS` or more intervals is then cut in two
    runs checked apart, so only the part of the range where the lobe changes fastest (near μ0) gets the finest
    steps. Returns the refined ``(ladder, evolved, breaks)``; InvalidInputError beyond :data:`MAX_SPLINE_LEVELS`
    scales."""
    s0 = law.at(mu0)
    if extent is None:
        extent = max(float(jnp.max(lobe.shape.support_radius(SUPPORT_TOL))) for lobe in evolved)
    ladder, evolved = [float(x) for x in ladder], list(evolved)
    breaks = spline_breaks(ladder, law)
    pending = list(zip(breaks[:-1], breaks[1:]))
    done = []
    while pending:
        a, b = pending.pop()  # from the last run down: indices below a stay valid
        mids = [math.sqrt(p * q) for p, q in zip(ladder[a:b], ladder[a + 1 : b + 1])]
        middles = [evolve(base_lobe, s0, law.at(mu), method) for mu in mids]
        error = spline_run_error(evolved[a : b + 1], middles, extent)
        if error <= tolerance:
            done.append(a)
            continue
        if len(ladder) + len(mids) > MAX_SPLINE_LEVELS:
            raise InvalidInputError(
                f"tolerance = {tolerance:g} needs more than {MAX_SPLINE_LEVELS} scales on the spline ladder (error "
                f"{error:.2g} on [{ladder[a]:g}, {ladder[b]:g}]); give a larger tolerance or a shorter ladder."
            )
        shift = b - a
        done = [k + shift if k > a else k for k in done]
        ladder[a : b + 1] = [x for pair in zip(ladder[a:b], mids) for x in pair] + [ladder[b]]
        evolved[a : b + 1] = [lobe for pair in zip(evolved[a:b], middles) for lobe in pair] + [evolved[b]]
        n = 2 * (b - a)
        pending += [(a, a + n // 2), (a + n // 2, a + n)] if n >= RUN_INTERVALS else [(a, a + n)]
    return np.asarray(ladder), evolved, sorted(set(done) | {len(ladder) - 1})


def _fit_law(fit, mu0):
    """A :class:`stats.MeasuredScaleLaw` with the fit's ``ΔΣ(μ0, μ_k) = Σ(μ0) − Σ(μ_k)``.

    Evolution needs only ``S(W, μ0)/S(W, μ_k)``, which for Gaussian statistics is ``exp(−WᵀΔΣ_k W/2)`` whatever
    ``Σ(μ0)`` is; the law takes ``Σ(μ0) = K`` with K the smallest multiple of the identity that keeps every
    ``K − ΔΣ_k`` positive definite (plus 1e-6), and ``Σ(μ_k) = K − ΔΣ_k``.
    """
    if "logit w" in tuple(getattr(fit, "names", ())):  # fitting.AnisotropicModel(increments="mixture")
        raise InvalidInputError(
            "the FitResult is of a model with mixture increments (heavy-tailed changes between scales, "
            "increments='mixture'), while a material evolves its lobe by Gaussian statistics of ΔΣ: that would render "
            f"another surface. Give instead the fit of Gaussian increments (increments='gaussian'), or {ACCEPTED}."
        )
    diffs = fit.covariance_differences
    if not diffs:
        raise InvalidInputError(
            "the FitResult has no covariance_differences (a model without finite second moments, e.g. GGX "
            f"statistics, or one scale only); give instead {ACCEPTED}."
        )
    fit_mu0 = float(diffs[0]["mu0"])
    if mu0 is not None and not math.isclose(float(mu0), fit_mu0, rel_tol=1e-9):
        raise InvalidInputError(f"mu0 = {mu0} differs from the fit's reference scale μ0 = {fit_mu0}; omit mu0.")
    values = [d["value"] for d in diffs]
    if any(v is None or any(x is None for row in v for x in row) for v in values):
        raise InvalidInputError(
            "the FitResult's covariance_differences are not all determined (None entries); a material needs "
            f"every ΔΣ(μ0, μ_k). Give instead {ACCEPTED}."
        )
    delta = np.array([np.zeros((2, 2))] + [np.asarray(v, float) for v in values])
    mus = np.array([fit_mu0] + [float(d["mu"]) for d in diffs])
    order = np.argsort(mus)
    k = max(0.0, float(np.max(np.linalg.eigvalsh(delta)[:, -1]))) + 1e-6
    cov = k * np.eye(2) - delta
    return stats.MeasuredScaleLaw(mus[order], cov[order]), fit_mu0


def as_scale_law(statistics, mu0):
    """``(law, μ0)`` from the statistics accepted by :func:`brdfscale.render.bsdf` (a LobeTable is not a law)."""
    if callable(getattr(statistics, "at", None)):
        if mu0 is None:
            raise InvalidInputError("mu0 is required with a scale law: the scale at which base_lobe holds.")
        return statistics, real(mu0, "mu0", minimum=0, strict=True)
    from brdfscale import fitting

    if isinstance(statistics, fitting.FitResult):
        return _fit_law(statistics, mu0)
    raise InvalidInputError(f"statistics must be {ACCEPTED}; got {type(statistics).__name__}.")


def default_scales(law, mu0: float, levels: int) -> np.ndarray:
    """The ladder ``μ0 · 2^k`` (k < levels); for a law measured over ``[μ_1, μ_n]`` (``.mu``), ``levels`` scales
    evenly spaced in ln μ over ``[max(μ0, μ_1), μ_n]`` together with the law's own scales in that range (a
    :class:`brdfscale.stats.MeasuredScaleLaw` is linear in ln μ between them, so the closed form's interpolation is
    exact there)."""
    measured = getattr(law, "mu", None)
    if measured is not None:
        measured = np.asarray(measured, float)
        lo, hi = max(mu0, float(np.min(measured))), float(np.max(measured))
        if hi > lo:
            inside = measured[(measured > lo) & (measured < hi)]
            merged = np.unique(np.concatenate([np.geomspace(lo, hi, levels), inside]))
            return merged[np.concatenate([[True], np.diff(np.log(merged)) > 1e-9])]
    return mu0 * 2.0 ** np.arange(levels)


def check_scales(scales) -> np.ndarray:
    s = np.atleast_1d(np.asarray(scales, dtype=float))
    if s.ndim != 1 or not np.all(np.isfinite(s)) or not np.all(s > 0) or not np.all(np.diff(s) > 0):
        raise InvalidInputError(f"scales must be finite positive increasing facet sizes μ; got {scales!r}.")
    return s


def evolved_lobes(
    base_lobe,
    statistics,
    *,
    mu0=None,
    scales=None,
    levels: int = DEFAULT_LEVELS,
    method: MethodName | AbstractMethod = "auto",
    tolerance: float | None = None,
    form: str = "table",
):
    """``(ladder, lobes, μ0, form)``: ``brdfscale.evolve(base_lobe, law.at(μ0), law.at(μ_k), method)`` (seed Eq.
    4.4) at every scale ``μ_k`` of the ladder (``scales``, or :func:`default_scales` with ``levels`` scales), the
    form they are rendered in (:func:`choose_form` of ``form``), and the ladder refined by :func:`refine_ladder` for
    that form where ``tolerance`` is given."""
    if not isinstance(base_lobe, AbstractLobe):
        raise InvalidInputError(
            f"base_lobe must be a brdfscale.lobes lobe (the BRDF at μ0); got {type(base_lobe).__name__}."
        )
    if np.ndim(base_lobe.amplitude) != 0:
        raise InvalidInputError(
            f"the Mitsuba plugin renders one channel, and base_lobe's amplitude has shape "
            f"{np.shape(base_lobe.amplitude)} (RGB): render each channel's lobe as its own material."
        )
    law, mu0 = as_scale_law(statistics, mu0)
    levels = integer(levels, "levels", 1)
    ladder = default_scales(law, mu0, levels) if scales is None else check_scales(scales)
    if isinstance(getattr(base_lobe, "shape", None), stats.Delta) and float(ladder[0]) <= mu0 * (1 + 1e-12):
        raise InvalidInputError(
            f"base_lobe is a mirror (a spike) and the ladder starts at μ0 = {mu0:g}, where the material's lobe is "
            "that spike, which no table or closed form holds: give scales above μ0 (scales=[…], e.g. "
            "mu0 · 2 ** k for k ≥ 1), or a base lobe with a width."
        )
    s0 = law.at(mu0)
    evolved = [evolve(base_lobe, s0, law.at(float(mu)), method) for mu in ladder]
    chosen = choose_form(form, evolved)
    if tolerance is not None and len(ladder) > 1:
        tolerance = real(tolerance, "tolerance", minimum=0, strict=True)
        ladder, evolved, breaks = chosen.refine(base_lobe, law, mu0, ladder, evolved, tolerance, method)
    else:
        breaks = spline_breaks(ladder, law) if chosen.name == "spline" else None
    return ladder, evolved, mu0, chosen, breaks


def tabulate(
    ladder, evolved, *, mu0, size: int = 128, extent: float | None = None, metadata=None, tolerance=None, form=None
) -> LobeTable:
    """The lobes ``evolved`` (one per scale of ``ladder``) on ``size × size`` nodes over ``[−extent, extent]²``
    (default extent: the largest ``support_radius(1e-4)`` of their shapes); with ``tolerance``, on more nodes where
    the ``form``'s interpolation (default the table's, bilinear) needs them (:func:`refine_grid`)."""
    size = integer(size, "size", 4)
    if extent is None:
        extent = max(float(jnp.max(lobe.shape.support_radius(SUPPORT_TOL))) for lobe in evolved)
    extent = real(extent, "extent", minimum=0, strict=True)
    if tolerance is not None:
        measure = (form or TABLE).measure
        size = refine_grid(evolved, extent, size, real(tolerance, "tolerance", minimum=0, strict=True), measure)
    meta = {"what": "brdfscale.render.lobe_table: base lobe evolved from mu0 to each scale", "mu0": float(mu0)}
    return LobeTable.from_lobes(ladder, evolved, extent=extent, size=size, metadata={**meta, **(metadata or {})})


def lobe_table(
    base_lobe: AbstractLobe | None,
    statistics,
    *,
    mu0: float | None = None,
    scales=None,
    levels: int = DEFAULT_LEVELS,
    size: int = 128,
    extent: float | None = None,
    method: MethodName | AbstractMethod = "auto",
    tolerance: float | None = None,
    form: str = "table",
) -> LobeTable:
    """The evolved lobe ``A·g(u, μ_k)`` tabulated at every scale of a ladder (what :func:`bsdf` renders).

    For each ``μ_k``: ``brdfscale.evolve(base_lobe, law.at(μ0), law.at(μ_k), method)`` (seed Eq. 4.4), its
    ``density(u)`` on ``size × size`` nodes over ``[−extent, extent]²`` (:meth:`brdfscale.exr.LobeTable.from_lobes`).

    Args:
        base_lobe: the lobe at μ0 (:mod:`brdfscale.lobes`); None with a LobeTable, which is returned as it is.
        statistics: a scale law or a FitResult (module docstring), or a LobeTable.
        mu0: the scale of ``base_lobe`` (a FitResult brings its own).
        scales: the ladder, increasing (default :func:`default_scales` with ``levels`` scales).
        size: nodes per axis. extent: the grid's half-width in slope units (default: the largest
            ``support_radius(1e-4)`` of the evolved lobes, so the tails beyond it hold < 1e-4 of each peak).
        method: the evolution's path (:func:`brdfscale.evolve`).
        tolerance: refine the ladder (:func:`refine_ladder`) until linear interpolation in ln μ is within this
            relative error of the exactly evolved lobe at every interval's midpoint, and the slope grid
            (:func:`refine_grid`) until bilinear interpolation is within it at every cell centre (None: the ladder
            and grid as given).
        form: ``"table"`` or ``"spline"``: the interpolation the ladder and grid are refined for; ``"spline"``
            also records the spline's breaks in the table's metadata (``"spline_breaks"``: :func:`spline_breaks`,
            e.g. at a measured law's own scales), which ``bsdf(None, table, form="spline")`` renders with.

    Raises InvalidInputError for statistics of another kind (naming those accepted), a missing ``mu0``, a bad ladder
    or grid; :class:`brdfscale.NoBRDFAtScaleError` where no lobe exists at a scale of the ladder (finer than the
    statistics allow).
    """
    if isinstance(statistics, LobeTable):
        if base_lobe is not None:
            raise InvalidInputError("a LobeTable is already evolved: pass base_lobe=None with it.")
        return statistics
    if FORMS.check(form) not in ("table", "spline"):
        raise InvalidInputError(f"form must be 'table' or 'spline' (a lobe table's interpolation); got {form!r}.")
    ladder, evolved, mu0, chosen, breaks = evolved_lobes(
        base_lobe, statistics, mu0=mu0, scales=scales, levels=levels, method=method, tolerance=tolerance, form=form
    )
    meta: dict = {"base_lobe": type(base_lobe).__name__, "statistics": type(statistics).__name__}
    if breaks is not None:
        meta["spline_breaks"] = [int(k) for k in breaks]
    return tabulate(ladder, evolved, mu0=mu0, size=size, extent=extent, metadata=meta, tolerance=tolerance, form=chosen)


def scalar_table(table: LobeTable) -> np.ndarray:
    """The table's values (k, n, n), refusing RGB tables (the plugin renders one channel)."""
    if table.values.ndim != 3:
        raise InvalidInputError(
            "the Mitsuba plugin renders one-channel lobe tables (k, n, n); this one is RGB (k, n, n, 3) — "
            "render each channel's table as its own material, or average them."
        )
    return np.asarray(table.values, dtype=float)
