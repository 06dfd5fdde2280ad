"""``register`` and ``bsdf``: the public entry points of the Mitsuba plugin (issue 33 item 1)."""

import sys
import threading

from .. import _mitsuba
from .._choices import FOOTPRINTS, FORMS, OUTPUTS
from .._errors import InvalidInputError
from .._evolve import AbstractMethod, MethodName
from ..exr import LobeTable
from ..lobes import AbstractLobe
from ._masking import masking_choice
from ._material import DEFAULT_LEVELS, evolved_lobes, gaussian_parameters, lobe_table, tabulate
from ._plugin import bsdf_class, check_filename, check_positive, Gaussians, PLUGIN, Splines, Tables


_REGISTERED: set[tuple[str, str]] = set()
_LOCK = threading.Lock()


def mitsuba(variant=None):
    """Mitsuba with ``variant``; without one, the variant already selected in this process, else
    :func:`brdfscale._mitsuba.mitsuba`'s default (Mitsuba's variant is process-wide: a scene built in one variant
    cannot hold objects of another)."""
    if variant is None:
        loaded = sys.modules.get("mitsuba")
        current = loaded.variant() if loaded is not None else None
        variant = current or None
    return _mitsuba.mitsuba(variant)


def register(variant: str | None = None) -> str:
    """Register the BSDF ``"brdfscale"`` and the integrator ``"brdfscale_footprint"`` with Mitsuba (for
    ``mi.load_dict``); idempotent, per variant. Returns the variant.

    In a scene dictionary: ``{"type": "brdfscale", "filename": "lobes.exr", "mu": 4.0, "masking": True,
    "texel": 0.01}`` — ``filename`` an evolved lobe table (:func:`brdfscale.exr.write_lobe_table`, e.g. of
    :func:`lobe_table`), ``mu`` a fixed scale (omit it to take the footprint), ``texel`` the scene length of one
    unit of μ.
    """
    from ._integrator import INTEGRATOR, integrator_class

    mi = mitsuba(variant)
    key = mi.variant()
    with _LOCK:
        if (key, PLUGIN) not in _REGISTERED:
            cls = bsdf_class(mi)
            mi.register_bsdf(PLUGIN, lambda props: check_filename(props) or cls(props))
            _REGISTERED.add((key, PLUGIN))
        if (key, INTEGRATOR) not in _REGISTERED:
            icls = integrator_class(mi)
            mi.register_integrator(INTEGRATOR, lambda props: icls(props))
            _REGISTERED.add((key, INTEGRATOR))
    return key


def bsdf(
    base_lobe: AbstractLobe | None,
    statistics,
    *,
    mu0: float | None = None,
    mu: float | None = None,
    masking=True,
    variant: str | None = None,
    texel: float = 1.0,
    scales=None,
    levels: int = DEFAULT_LEVELS,
    size: int = 128,
    extent: float | None = None,
    method: MethodName | AbstractMethod = "auto",
    tolerance: float | None = None,
    masking_shapes=None,
    form: str = FORMS.default,
):
    """A Mitsuba BSDF rendering ``base_lobe`` (the BRDF at μ0) evolved with ``statistics`` to each interaction's scale.

    The lobe is evolved in JAX once, to every scale of a ladder (:func:`lobe_table`: ``scales``, or ``levels``
    scales ``μ0·2^k``), so rendering never calls JAX. Where every evolved lobe is Gaussian (a Gaussian/Beckmann base
    lobe with Gaussian statistics: :func:`brdfscale.evolve`'s closed form, covariances add) the plugin keeps each
    scale's amplitude, mean and covariance, interpolates them linearly in ln μ and evaluates the Gaussian and its
    Smith masking exactly (``form="closed"``); otherwise the lobes are tabulated and Mitsuba interpolates the table
    (bilinear in the slope offset, linear in ln μ; ``form="table"``; or by tricubic B-splines, ``form="spline"``).
    μ is clamped to the ladder's ends. The object goes into ``mi.load_dict`` scenes as any BSDF
    (``{"type": "rectangle", "bsdf": bsdf(...)}``).

    Args:
        base_lobe: a :mod:`brdfscale.lobes` lobe at μ0 (None with an evolved LobeTable).
        statistics: a scale law (anything with ``.at(μ)``: :class:`brdfscale.stats.GaussianSurface`,
            :class:`~brdfscale.stats.ScaledFamily`, :class:`~brdfscale.stats.MeasuredScaleLaw`, …), a
            :class:`fitting.FitResult` (its covariance differences), or an evolved
            :class:`brdfscale.exr.LobeTable` (e.g. read from EXR).
        mu0: the scale of ``base_lobe`` (same length unit as the law's μ).
        mu: a fixed observation scale for every interaction (the fallback for any integrator); None: the
            interaction's footprint, which :func:`FootprintIntegrator` provides (Mitsuba's stock integrators do not:
            there the footprint is 0 and the ladder's finest scale is used).
        masking: True (Smith, height-correlated ``G₂ = 1/(1 + Λ_i + Λ_o)``), False, or a
            :class:`brdfscale.lobes.SmithMasking` / :class:`~brdfscale.lobes.NoMasking` choice.
        variant: a Mitsuba variant; default the one already selected, else the first that runs here.
        texel: the scene length of one unit of μ (footprint lengths are divided by it).
        scales, levels, size, extent, method, tolerance: the ladder and grid of :func:`lobe_table` (``tolerance``
            refines the ladder in ln μ and the slope grid until their interpolation is within it of the evolved
            lobe; docs/render.md).
        masking_shapes: one :mod:`brdfscale.stats` slope density per scale of the ladder whose Smith Λ makes the
            masking tables instead of the evolved shapes' (e.g. Gaussians of the same covariance where the generic
            quadrature of an evolved non-Gaussian shape is too slow); requires ``scales`` (table form only), or
            one per scale of a LobeTable (whose own tabulated shapes' quadrature is slow).
        form: ``"auto"`` (closed where the evolved lobes are Gaussian, else table), ``"closed"``, ``"table"``
            (bilinear in the offset, linear in ln μ) or ``"spline"`` (tricubic B-splines: the accurate tables)
            (docs/render.md, "Accuracy").

    Raises InvalidInputError for statistics of another kind or bad options (naming what is accepted),
    :class:`brdfscale.NoBRDFAtScaleError` where the lobe has no BRDF at a scale of the ladder,
    :class:`brdfscale.MissingDependencyError` without Mitsuba.
    """
    if mu is not None:
        mu = check_positive(mu, "mu", "a fixed observation scale, in the law's length unit")
    texel = check_positive(texel, "texel", "the scene length of one unit of μ")
    choice = masking_choice(masking)
    if scales is None and mu is not None and base_lobe is not None:
        scales = [mu]  # one scale is all a fixed-μ material needs
    if masking_shapes is not None and form == "auto":
        form = "table"  # masking shapes of one's own are for tables
    if isinstance(statistics, LobeTable):
        if form not in ("auto", "table", "spline"):
            raise InvalidInputError(
                f"a LobeTable is rendered from its values: form must be 'auto', 'table' or 'spline'; got {form!r}."
            )
        table = lobe_table(base_lobe, statistics)
        if mu0 is not None or scales is not None:
            raise InvalidInputError(
                "mu0= and scales= are for statistics; a LobeTable is already evolved at its own scales: omit them "
                "(mu= fixes the scale the table is rendered at)."
            )
        shapes = None
        if masking_shapes is not None:
            shapes = list(masking_shapes)
            if len(shapes) != len(table.scales):
                raise InvalidInputError(
                    f"masking_shapes needs one slope density per scale of the LobeTable ({len(table.scales)}); got "
                    f"{len(shapes)}."
                )
        host = (Splines if form == "spline" else Tables)(table, choice, mu=mu, texel=texel, shapes=shapes)
    else:
        ladder, evolved, mu0, chosen, breaks = evolved_lobes(
            base_lobe, statistics, mu0=mu0, scales=scales, levels=levels, method=method, tolerance=tolerance, form=form
        )
        params = gaussian_parameters(evolved) if chosen.name == "closed" else None
        if params is not None:
            if masking_shapes is not None:
                raise InvalidInputError(
                    "masking_shapes is for tabulated lobes (form='table'); the closed form masks with its own "
                    "Gaussians exactly."
                )
            host = Gaussians(ladder, params, choice, mu=mu, texel=texel)
        else:
            host = _tables(
                ladder, evolved, mu0, choice, mu, texel, size, extent, tolerance, scales, masking_shapes, chosen, breaks
            )
    mi = mitsuba(variant)
    obj = bsdf_class(mi)(mi.Properties(PLUGIN))
    obj.load(host)
    return obj


def _tables(
    ladder, evolved, mu0, choice, mu, texel, size, extent, tolerance, scales, masking_shapes, form, breaks
) -> Tables | Splines:
    """The tabulated form (``form``: the table's or the spline's, with its ``breaks``) of :func:`bsdf`'s evolved
    lobes, with the masking tables of their shapes or of ``masking_shapes``."""
    meta = None if breaks is None else {"spline_breaks": [int(k) for k in breaks]}
    table = tabulate(ladder, evolved, mu0=mu0, size=size, extent=extent, tolerance=tolerance, form=form, metadata=meta)
    shapes = [lobe.shape for lobe in evolved]
    if masking_shapes is not None:
        if scales is None or tolerance is not None or len(list(masking_shapes)) != len(ladder):
            raise InvalidInputError(
                "masking_shapes needs scales= (and no tolerance, which changes the ladder): one slope density "
                f"per scale; got {len(list(masking_shapes))} for {len(ladder)} scales."
            )
        shapes = list(masking_shapes)
    return (Splines if form.name == "spline" else Tables)(table, choice, mu=mu, texel=texel, shapes=shapes)


def FootprintIntegrator(  # noqa: N802 (it builds a Mitsuba object of the current variant's class)
    *,
    max_depth: int = 3,
    output: str = OUTPUTS.default,
    footprint: str = FOOTPRINTS.default,
    variant: str | None = None,
):
    """The path tracer ``"brdfscale_footprint"`` (brdfscale/render/_integrator.py), as a Mitsuba integrator object.

    It fills the uv partials of every first hit from the camera ray's differentials, so a :func:`bsdf` without a
    fixed ``mu`` renders each pixel at its footprint ``μ = √(pixel's area on the surface) / texel``. ``max_depth``:
    path segments (2: direct lighting); ``output="footprint"``: the footprint length (scene units) instead of
    radiance; ``footprint="sample"``: Mitsuba's per-sample differentials (``1/√spp`` of the pixel's).
    Use it as ``mi.render(scene, integrator=FootprintIntegrator())`` or, after :func:`register`, as
    ``{"type": "brdfscale_footprint"}`` in a scene dictionary.
    """
    from ._integrator import check_options, INTEGRATOR

    check_options(max_depth, output, footprint)  # here: Mitsuba would turn the plugin's exception into RuntimeError
    mi = mitsuba(variant)
    register(mi.variant())
    return mi.load_dict({"type": INTEGRATOR, "max_depth": max_depth, "output": output, "footprint": footprint})
