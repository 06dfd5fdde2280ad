"""Figures of measurement sets and of MCMC chains."""

import numpy as np

from .._errors import InvalidInputError
from ._common import colorbar, colormap, figure, luminance, luminance_sigma, SLOPE_DENSITY, small_ticks


def _selection(images, count: int) -> list[int]:
    if images is None:
        return list(range(count))
    try:
        chosen = [int(k) for k in images] if not isinstance(images, (str, bytes)) else None
    except (TypeError, ValueError):
        chosen = None
    if not chosen or any(isinstance(k, bool) for k in images) or any(not 0 <= k < count for k in chosen):
        raise InvalidInputError(
            f"images must be a non-empty sequence of image indices in [0, {count - 1}]; got {images!r}."
        )
    return chosen


def measurements(mset, *, images=None):
    """Every image of a measurement set: the values and, where stored, their σ.

    One row per image (its index, μ with its length unit — the set's ``metadata["unit"]``, px
    when it has none — and incident angle θ_i in the title), columns: (1) the
    lobe ``A·g(u)`` over the slope offsets ``u`` (per unit slope²; masked pixels grey), (2) its
    per-pixel σ (same unit) where any image stores one (an image without σ leaves that panel
    blank). RGB images are shown as Rec. 709 luminance Y (σ combined for independent channel
    noise). Axes: per image 2 (value image and colour bar), plus 2 for σ when the set has any.

    Args:
        mset: a :class:`brdfscale.MeasurementSet` (or one :class:`brdfscale.LobeImage`).
        images: indices of the images to draw (default all).

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: not a measurement set or image, or bad ``images``.
    """
    from .._measurement import LobeImage, MeasurementSet

    if isinstance(mset, LobeImage):
        mset = MeasurementSet((mset,))
    if not isinstance(mset, MeasurementSet):
        raise InvalidInputError(f"plot.measurements needs a brdfscale.MeasurementSet; got {type(mset).__name__}.")
    chosen = _selection(images, len(mset.images))
    unit = mset.metadata.get("unit") if isinstance(mset.metadata.get("unit"), str) else None
    with_sigma = any(mset.images[k].sigma is not None for k in chosen)
    columns = 2 if with_sigma else 1
    fig = figure(3.7 * columns, 3.0 * len(chosen))
    axes = fig.subplots(len(chosen), columns, squeeze=False)
    cmap = colormap("magma").with_extremes(bad="0.8")
    for row, k in enumerate(chosen):
        image = mset.images[k]
        e = image.extent
        rgb = image.values.ndim == 3
        values = luminance(image.values).astype(float)
        if image.mask is not None:
            values = np.where(image.mask, values, np.nan)
        theta, _ = image.incident_angles
        quantity = "Y of A·g(u)" if rgb else "A·g(u)"
        ax = axes[row, 0]
        shown = ax.imshow(values, origin="lower", extent=(-e, e, -e, e), cmap=cmap)
        colorbar(fig, shown, ax, f"{quantity} ({SLOPE_DENSITY})")
        ax.set_title(
            f"image {k}: μ = {image.mu:.4g} {unit or 'px'}, θ_i = {theta:.3g}°"
            + (" (RGB → luminance Y)" if rgb else ""),
            fontsize=9,
        )
        ax.set_xlabel("u_x (slope)")
        ax.set_ylabel("u_y (slope)")
        small_ticks(ax)
        if not with_sigma:
            continue
        ax = axes[row, 1]
        if image.sigma is None:
            ax.set_axis_off()
            ax.text(0.5, 0.5, f"image {k}: no σ stored", ha="center", va="center", transform=ax.transAxes, fontsize=9)
            continue
        sigma = luminance_sigma(image.sigma).astype(float)
        if image.mask is not None:
            sigma = np.where(image.mask, sigma, np.nan)
        shown = ax.imshow(
            sigma, origin="lower", extent=(-e, e, -e, e), cmap=colormap("viridis").with_extremes(bad="0.8")
        )
        colorbar(fig, shown, ax, f"σ of {'Y' if rgb else 'A·g(u)'} ({SLOPE_DENSITY})")
        ax.set_title(f"image {k}: σ per pixel (μ = {image.mu:.4g} {unit or 'px'})", fontsize=9)
        ax.set_xlabel("u_x (slope)")
        ax.set_ylabel("u_y (slope)")
        small_ticks(ax)
    return fig


def chains(samples, *, coordinates: int = 8):
    """The MCMC chains of :func:`fitting.sample`: trace plots, burn-in marked.

    Panels, one above the other: (1) the log-posterior of every trajectory (emcee walker or
    NUTS/HMC chain) against the step, (2 …) each θ coordinate (the model's unconstrained
    coordinates, e.g. ``log amplitude``) of every trajectory, one colour per independent chain
    (for emcee: per ensemble); the dotted line is the burn-in or warm-up the diagnostics
    discard. The title names the sampler's trajectories ("4 × 32 walkers", "4 NUTS chains").
    Axes: 1 + the number of coordinates drawn.

    Args:
        samples: a :class:`fitting.SampleResult`.
        coordinates: the most θ coordinates drawn (the first ones), ≥ 1.

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: not a SampleResult, or ``coordinates`` not an integer ≥ 1.
    """
    from .._validation import integer

    if type(samples).__name__ != "SampleResult" or not hasattr(samples, "chain"):
        raise InvalidInputError(f"plot.chains needs the SampleResult of fitting.sample; got {type(samples).__name__}.")
    coordinates = integer(coordinates, "coordinates", 1)
    chain, log_prob = np.asarray(samples.chain), np.asarray(samples.log_prob)
    n_steps, n_walkers, d = chain.shape
    shown = min(d, coordinates)
    fig = figure(7.5, 1.5 * (shown + 1) + 0.6)
    axes = fig.subplots(shown + 1, 1, sharex=True, squeeze=False)[:, 0]
    steps = np.arange(n_steps)
    alpha = max(0.08, min(0.6, 8 / n_walkers))
    finite = np.where(np.isfinite(log_prob), log_prob, np.nan)
    axes[0].plot(steps, finite, color="C0", lw=0.6, alpha=alpha)
    axes[0].set_ylabel("log posterior", fontsize=8)
    sampler, runs = samples.sampler, int(samples.chains)
    if sampler == "emcee":
        what = f"{runs} × {n_walkers // max(runs, 1)} walkers" if runs > 1 else f"{n_walkers} walkers"
        start = "burn-in"
    else:
        what = f"{n_walkers} {sampler.upper()} chains"
        start = "warm-up"
    axes[0].set_title(
        f"{what}, {n_steps} steps; {start} {samples.burn} (dotted), acceptance {samples.acceptance:.2f}", fontsize=9
    )
    colours = [f"C{(i + 1) % 10}" for i in range(runs)] if runs > 1 else ["C1"]
    per = max(n_walkers // max(runs, 1), 1)
    for j in range(shown):
        for i, colour in enumerate(colours):  # one colour per independent chain (emcee: per ensemble)
            axes[j + 1].plot(steps, chain[:, i * per : (i + 1) * per, j], color=colour, lw=0.6, alpha=alpha)
        axes[j + 1].set_ylabel(samples.names[j], fontsize=8)
    for ax in axes:
        ax.axvline(samples.burn, color="k", lw=0.8, ls=":")
        small_ticks(ax)
    axes[-1].set_xlabel("step")
    if d > shown:
        fig.suptitle(f"first {shown} of {d} coordinates", fontsize=9)
    return fig
