"""Figures of lobes and of facet-slope statistics."""

import math
from collections.abc import Sequence

import numpy as np

from .._errors import BrdfscaleError, InvalidInputError, SingularDensityError
from ._common import (
    colorbar,
    colormap,
    figure,
    grid_points,
    positive_number,
    require_concrete,
    require_one,
    SLOPE_DENSITY,
    small_ticks,
)


def _support(density, tol: float = 1e-3) -> float:
    """A radius that holds the density above ``tol`` of its peak (0 when there is none to use)."""
    try:
        r = float(np.max(np.asarray(density.support_radius(tol))))
    except (BrdfscaleError, TypeError, ValueError, NotImplementedError):  # no usable radius: the caller's default
        return 0.0
    return r if math.isfinite(r) and r > 0 else 0.0


def lobe(lobe, incident=None, *, extent=None, size: int = 129, log: bool = False):
    """The lobe ``A·g(u)`` on the plane of half-vector slope offsets ``u = m_s − m∞``.

    Panels: (1) the lobe as an image over ``u ∈ [−extent, extent]²`` with a colour bar
    ``A·g(u)`` (per unit slope²); (2) its slices along ``u_x`` (``u_y = 0``, solid) and ``u_y``
    (``u_x = 0``, dashed); with ``incident`` given, (3) the BRDF ``ρ(i, o) = A F(i, o) g(m_s(i, o))``
    (1/sr, :meth:`brdfscale.lobes.AbstractLobe.evaluate`) over the projected outgoing directions
    ``(o_x, o_y)`` about the mirror direction (marked +) with its colour bar. Axes: 3 (the image,
    its colour bar, the slices), 5 with ``incident``. A radially symmetric lobe is evaluated
    along one ray (``4·size`` radii) and drawn by linear interpolation in ``|u|``, so a spectral
    path (e.g. 8192 Gauss–Legendre nodes per query) costs hundreds of queries, not size².

    Args:
        lobe: a :mod:`brdfscale.lobes` lobe (e.g. what :func:`brdfscale.evolve` returns), one
            (not a vmapped batch), with concrete values.
        incident: unit direction towards the light (3,), z > 0, for panel 3; None: no panel 3.
        extent: half-width of the offset window (slope units); default the radius beyond which
            the lobe stays below 10⁻³ of its peak (its shape's ``support_radius``).
        size: grid points per axis (odd: a node at u = 0), 9 … 2049.
        log: logarithmic colour scale and slices (four decades below the peak).

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: not a lobe, a batch, traced values, a lobe with no pointwise density
            (a mirror: δ), or a bad ``incident``/``extent``/``size``.
    """
    import jax.numpy as jnp

    from ..lobes import AbstractLobe

    if not isinstance(lobe, AbstractLobe):
        raise InvalidInputError(f"plot.lobe needs a brdfscale.lobes lobe; got {type(lobe).__name__}.")
    require_concrete(lobe, "lobe")
    require_one(tuple(np.shape(lobe.amplitude)), "lobe (its amplitude)")
    size = grid_points(size)
    if extent is None:
        extent = _support(lobe.shape) or 1.0
    extent = positive_number(extent, "extent")
    dtype = jnp.result_type(lobe.amplitude, float)
    x = np.linspace(-extent, extent, size)
    offsets = np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)
    directions = None if incident is None else _outgoing(incident, extent, size)
    radii = [np.linalg.norm(offsets, axis=-1)] + ([] if directions is None else [directions[3]])
    density = _density_of(lobe, dtype, max(float(np.nanmax(r)) for r in radii), size)
    values = density(offsets)
    peak = float(np.nanmax(values))
    panels = 2 if incident is None else 3
    fig = figure(3.9 * panels, 3.4)
    axes = fig.subplots(1, panels, squeeze=False)[0]
    norm, shown = _norm(log, peak, values)
    image = axes[0].imshow(
        shown,
        origin="lower",
        extent=(-extent, extent, -extent, extent),
        cmap="magma",
        norm=norm,
    )
    colorbar(fig, image, axes[0], f"A·g(u) ({SLOPE_DENSITY})")
    axes[0].set_xlabel("u_x (slope)")
    axes[0].set_ylabel("u_y (slope)")
    axes[0].set_title(f"{_lobe_name(lobe)}, A = {float(lobe.amplitude):.4g}", fontsize=9)
    mid = size // 2
    ax = axes[1]
    ax.plot(x, values[mid, :], color="C0", lw=1.2, label="along u_x (u_y = 0)")
    ax.plot(x, values[:, mid], color="C1", lw=1.0, ls="--", label="along u_y (u_x = 0)")
    if log:
        ax.set_yscale("log")
        ax.set_ylim(norm.vmin, peak * 2)
    ax.set_xlabel("u (slope)")
    ax.set_ylabel(f"A·g(u) ({SLOPE_DENSITY})")
    ax.set_title("slices through u = 0", fontsize=9)
    ax.legend(fontsize=7)
    if incident is not None:
        _brdf_panel(fig, axes[2], lobe, density, directions, log)
    for ax in axes:
        small_ticks(ax)
    return fig


def _lobe_name(lobe) -> str:
    """``Beckmann lobe``; an evolved lobe by its path (``evolved lobe (radial path)``)."""
    discretisation = getattr(lobe.shape, "discretisation", None)
    if discretisation is not None:
        return f"evolved lobe ({discretisation.path} path)"
    name = type(lobe).__name__
    return f"{type(lobe.shape).__name__} lobe" if name == "Lobe" else f"{name} lobe"


def _norm(log: bool, peak: float, values):
    """The colour scale and the values to draw with it: on a log scale from 10⁻⁴ of the peak up,
    the values raised to that floor (zeros and negatives have no place on it)."""
    from matplotlib.colors import LogNorm, Normalize

    if log:
        top = peak if peak > 0 else 1.0
        return LogNorm(vmin=top * 1e-4, vmax=top), np.maximum(values, top * 1e-4)
    return Normalize(), values


def _pointwise(s, m, dtype):
    """``s(m)`` as a NumPy array, or None where ``s`` has no pointwise density: a generalised
    function (a plus-distribution), or a point mass (its density raises SingularDensityError)."""
    import jax.numpy as jnp

    from ..stats import AbstractSlopeDensity

    if not isinstance(s, AbstractSlopeDensity):
        return None
    try:
        return np.asarray(s.density(jnp.asarray(m, dtype=dtype)))
    except SingularDensityError:
        return None


def _density_of(lobe, dtype, reach: float, size: int):
    """``u ↦ A·g(u)`` on NumPy offsets (..., 2). A radially symmetric lobe is evaluated once along
    a ray, at ``4·size`` radii up to ``reach``, and read off by linear interpolation in ``|u|``: a
    spectral path's cost grows with the number of queries (8192 Gauss–Legendre nodes per query
    for a narrow radial lobe), the image's would be size² of them."""
    import jax.numpy as jnp

    def direct(u):
        try:
            return np.asarray(lobe.density(jnp.asarray(u, dtype=dtype)))
        except SingularDensityError:
            raise InvalidInputError(
                f"the lobe's shape ({type(lobe.shape).__name__}) has a point mass and no pointwise density to draw "
                "(a mirror: δ); plot.statistics(lobe.shape) draws its transform."
            ) from None

    probe = direct(np.zeros(2))
    require_one(probe.shape, "lobe")
    if not lobe.shape.isotropic:
        return direct
    r = np.linspace(0.0, reach, 4 * size)
    profile = direct(np.stack([r, np.zeros_like(r)], axis=-1))
    return lambda u: np.interp(np.linalg.norm(u, axis=-1), r, profile)


def _outgoing(incident, extent, size):
    """The projected outgoing directions about the mirror direction of ``incident``:
    ``(i, o (n, n, 3), visible (n, n), |u| (n, n), (o_x, o_y) axes)``."""
    import jax.numpy as jnp

    from ..geometry import half_slope, validate_directions

    try:
        i = np.asarray(validate_directions(jnp.asarray(incident, dtype=float), "incident"), dtype=float)
    except (TypeError, ValueError):
        raise InvalidInputError(f"incident must be a unit 3-vector with z > 0; got {incident!r}.") from None
    if i.shape != (3,):
        raise InvalidInputError(f"incident must be one unit 3-vector (shape (3,)); got shape {i.shape}.")
    mirror = np.array([-i[0], -i[1], i[2]])
    half = min(1.0, 2.5 * extent)
    ox = np.linspace(mirror[0] - half, mirror[0] + half, size)
    oy = np.linspace(mirror[1] - half, mirror[1] + half, size)
    X, Y = np.meshgrid(ox, oy, indexing="xy")
    r2 = X**2 + Y**2
    visible = r2 < 1 - 1e-6
    z = np.sqrt(np.where(visible, 1 - r2, 1.0))
    o = np.stack([np.where(visible, X, 0.0), np.where(visible, Y, 0.0), z], axis=-1)
    u = np.asarray(half_slope(jnp.asarray(np.broadcast_to(i, o.shape)), jnp.asarray(o)))
    return i, o, visible, np.where(visible, np.linalg.norm(u, axis=-1), np.nan), (ox, oy), u


def _brdf_panel(fig, ax, lobe, density, directions, log):
    """ρ(i, o) = A F(i, o) g(m_s(i, o)) over the projected outgoing directions (flat m∞)."""
    import jax.numpy as jnp

    from ..geometry import microfacet_factor

    i, o, visible, _, (ox, oy), u = directions
    factor = np.asarray(microfacet_factor(jnp.asarray(np.broadcast_to(i, o.shape)), jnp.asarray(o)))
    rho = np.where(visible, density(u) * factor, np.nan)
    peak = float(np.nanmax(rho)) if np.any(visible) else 1.0
    norm, shown = _norm(log, peak, rho)
    cmap = colormap("magma").with_extremes(bad="0.85")
    image = ax.imshow(
        shown,
        origin="lower",
        cmap=cmap,
        norm=norm,
        extent=(ox[0], ox[-1], oy[0], oy[-1]),
    )
    colorbar(fig, image, ax, "ρ(i, o) (1/sr)")
    mirror = (-i[0], -i[1])
    ax.plot([mirror[0]], [mirror[1]], "+", color="C2", ms=9, mew=1.5, label="mirror direction")
    theta = math.degrees(math.acos(min(1.0, i[2])))
    ax.set_title(f"BRDF at θ_i = {theta:.3g}° (grey: below the horizon)", fontsize=9)
    ax.set_xlabel("o_x (projected outgoing direction)")
    ax.set_ylabel("o_y")
    ax.legend(fontsize=7, loc="upper right")


def _decay(density) -> float:
    """A frequency by which ``S`` has decayed: its bandwidth at 10⁻³, at most 12 over its support
    radius (a disk's transform rings out slowly; the figure shows its main lobes); 0 for none."""
    try:
        band = float(np.max(np.asarray(density.bandwidth(1e-3))))
    except (BrdfscaleError, TypeError, ValueError, NotImplementedError):
        band = math.inf
    radius = _support(density)
    band = min(band, 12.0 / radius) if radius > 0 else band
    return band if math.isfinite(band) and band > 0 else 0.0


def _entries(statistics, mu, labels):
    """``[(label, distribution)]`` from one distribution, a sequence of them, or a scale law at ``mu``."""
    from ..stats import AbstractDistribution, AbstractScaleLaw

    if isinstance(statistics, AbstractScaleLaw):
        if mu is None:
            raise InvalidInputError("plot.statistics of a scale law needs the facet sizes: mu=[μ1, μ2, …].")
        scales = np.atleast_1d(np.asarray(mu, dtype=float)) if not isinstance(mu, (str, bytes)) else None
        if scales is None or scales.ndim != 1 or scales.size == 0 or not np.all(np.isfinite(scales) & (scales > 0)):
            raise InvalidInputError(f"mu must be one or more positive facet sizes; got {mu!r}.")
        # a scale law carries no unit: μ is in the length units it was built in (the scene's)
        entries = [(f"μ = {m:.4g} (length units)", statistics.at(float(m))) for m in scales]
    else:
        if mu is not None:
            raise InvalidInputError(
                "mu= applies to a scale law (stats.ScaledFamily, GaussianSurface, …); the "
                f"statistics given are {type(statistics).__name__}."
            )
        items = [statistics] if isinstance(statistics, AbstractDistribution) else statistics
        if not isinstance(items, Sequence) or not items or not all(isinstance(s, AbstractDistribution) for s in items):
            raise InvalidInputError(
                "plot.statistics needs a brdfscale.stats distribution, a non-empty sequence of them, or a scale law "
                f"with mu=; got {type(statistics).__name__}."
            )
        entries = [(type(s).__name__, s) for s in items]
    if labels is not None:
        labels = [labels] if isinstance(labels, str) else list(labels)
        if len(labels) != len(entries) or not all(isinstance(t, str) for t in labels):
            raise InvalidInputError(f"labels must be {len(entries)} strings, one per statistic; got {labels!r}.")
        entries = [(t, s) for t, (_, s) in zip(labels, entries)]
    for label, s in entries:
        require_concrete(s, f"statistics {label!r}")
    return entries


def statistics(statistics, *, mu=None, labels=None, extent=None, w_max=None, size: int = 257):
    """Facet-slope statistics: the density ``s(m)`` and its transform ``S(W)``.

    Panels: (1) slices of the density along ``m_x`` (solid; along ``m_y`` dashed where a
    statistic is not isotropic), per unit slope²; point masses (δ) and generalised functions
    have no pointwise density and are listed in the panel's legend only; (2) the transform
    ``Re S(W)`` along ``W_x`` (and ``W_y``, dashed), W in radians per unit slope — the factor
    by which the statistics enter seed Eq. 4.4. Axes: 2.

    Args:
        statistics: a :mod:`brdfscale.stats` distribution (also :mod:`brdfscale.plus`), a
            sequence of them, or a scale law (``AbstractScaleLaw``) drawn at the facet sizes ``mu``.
        mu: facet sizes for a scale law (legend: μ).
        labels: one legend label per statistic (default: the class names, or for a law
            "μ = … (length units)": a law carries no unit).
        extent: half-width of the slope window; default the largest radius holding a density
            above 10⁻³ of its peak.
        w_max: the largest frequency drawn; default where the slowest transform has fallen to
            10⁻³ (``bandwidth``, at most 12 over the statistic's support radius), or 12/extent.
        size: points per slice (odd), 9 … 2049.

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: something that is not a statistic, a batch (vmapped), traced values,
            ``mu`` missing for a law or given without one, bad ``labels``/``extent``/``w_max``/``size``.
    """
    import jax.numpy as jnp

    entries = _entries(statistics, mu, labels)
    size = grid_points(size)
    for label, s in entries:
        require_one(tuple(np.shape(s.cf(jnp.zeros(2)))), f"statistics {label!r}")
    if extent is None:
        extent = max((_support(s) for _, s in entries), default=0.0) or 1.0
    extent = positive_number(extent, "extent")
    if w_max is None:
        w_max = max((_decay(s) for _, s in entries), default=0.0) or 12.0 / extent
    w_max = positive_number(w_max, "w_max")
    m = np.linspace(-extent, extent, size)
    w = np.linspace(0.0, w_max, size)
    zeros = np.zeros_like(m)
    fig = figure(10.0, 3.8)
    ax_s, ax_S = fig.subplots(1, 2)
    colors = colormap("viridis")(np.linspace(0.0, 0.9, len(entries))) if len(entries) > 1 else ["C0"]
    for (label, s), color in zip(entries, colors):
        dtype = jnp.result_type(*[leaf for leaf in _leaves(s)] or [float], float)
        both = not s.isotropic
        along_x = _pointwise(s, np.stack([m, zeros], -1), dtype)
        if along_x is None:
            ax_s.plot([], [], color=color, label=f"{label}: no pointwise density (point mass)")
        else:
            ax_s.plot(m, along_x, color=color, lw=1.2, label=label)
            if both:
                ax_s.plot(m, _pointwise(s, np.stack([zeros, m], -1), dtype), color=color, lw=1.0, ls="--")
        ax_S.plot(
            w,
            np.real(np.asarray(s.cf(jnp.asarray(np.stack([w, np.zeros_like(w)], -1), dtype=dtype)))),
            color=color,
            lw=1.2,
            label=label,
        )
        if both:
            ax_S.plot(
                w,
                np.real(np.asarray(s.cf(jnp.asarray(np.stack([np.zeros_like(w), w], -1), dtype=dtype)))),
                color=color,
                lw=1.0,
                ls="--",
            )
    anisotropic = any(not s.isotropic for _, s in entries)
    ax_s.set_xlabel("slope m_x" + (" (solid), m_y (dashed)" if anisotropic else " (through m = 0)"))
    ax_s.set_ylabel(f"s(m) ({SLOPE_DENSITY})")
    ax_s.set_title("facet-slope density", fontsize=9)
    ax_S.set_xlabel("W_x" + (" (solid), W_y (dashed)" if anisotropic else "") + " (rad per unit slope)")
    ax_S.set_ylabel("Re S(W)")
    ax_S.axhline(0.0, color="0.7", lw=0.6)
    ax_S.set_title("transform S(W) = ∫ s(m) exp(−iW·m) d²m", fontsize=9)
    for ax in (ax_s, ax_S):
        ax.legend(fontsize=7)
        small_ticks(ax)
    return fig


def _leaves(tree):
    import jax

    return [
        leaf
        for leaf in jax.tree_util.tree_leaves(tree)
        if hasattr(leaf, "dtype") and np.issubdtype(np.dtype(leaf.dtype), np.floating)
    ]
