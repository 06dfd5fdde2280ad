"""The figure of a scene plan: what is computed where."""

import numpy as np

from .._errors import InvalidInputError
from ._common import colorbar, colormap, figure, require_concrete, small_ticks


def _queries_of(part):
    """``(rows, μ, |u| or None, scale nodes)`` of one material's part: the scene's query indices it
    serves, each query's facet size and half-vector slope offset (None on the SO(3) path, whose
    keys are orientations), and the scales at which it evaluates tables."""
    step = part.step
    inverse = np.asarray(part.inverse)
    if hasattr(step, "log_mu"):
        mu_key = np.exp(np.asarray(step.log_mu))
        nodes = np.exp(np.asarray(step.nodes))
    else:  # the closed form: exact at each distinct scale
        nodes = np.asarray(step.mu)
        mu_key = nodes[np.asarray(step.scale)]
    u = np.linalg.norm(np.asarray(step.u), axis=-1)[inverse] if hasattr(step, "u") else None
    return np.asarray(part.rows), mu_key[inverse], u, nodes


def _label(plan, p) -> str:
    material = plan.materials[p.material]
    return (
        f"material {p.material} ({type(material.lobe).__name__}): {p.path}, {p.queries} queries, "
        f"error ≤ {p.predicted_error:.2g}"
    )


def plan(plan):
    """What a :func:`brdfscale.scene.plan` computes where.

    For a camera scene (:func:`brdfscale.scene.camera_scene`): (1) the image coloured by the
    part that evaluates each pixel (material and path: closed form, radial, grid, SO(3); grey:
    no query, e.g. sky), (2) the facet size ``log₁₀ μ`` each pixel resolves, with its colour
    bar, (3) the queries' μ per part (histogram) with the part's scale nodes — where it
    evaluates the evolved lobe exactly; between them it interpolates in log μ — as ticks along
    the top (none for the closed form, exact at every μ); its legend names the parts' colours.
    Axes: 4. Without a camera, (1) is each query's half-vector slope offset ``|u|``
    against μ, coloured by part (SO(3) parts, whose keys are orientations, are listed in the
    legend only), and (2) is the histogram of (3). Axes: 2. The legend gives each part's
    path, query count and predicted error (``plan.explain()`` says why).

    Args:
        plan: a :class:`brdfscale.scene.Plan` with concrete values.

    Returns a ``matplotlib.figure.Figure`` (made without pyplot).

    Raises:
        InvalidInputError: not a Plan, or traced values.
    """
    from ..scene import Plan

    if not isinstance(plan, Plan):
        raise InvalidInputError(f"plot.plan needs a brdfscale.scene.Plan (from scene.plan); got {type(plan).__name__}.")
    require_concrete(plan, "plan")
    parts = [(p, *_queries_of(p)) for p in plan.parts]
    colors = [colormap("tab10")(k % 10) for k in range(len(parts))]
    resolution = None if plan.pixels is None else plan.resolution  # (rows, columns) of a camera scene
    camera = resolution is not None
    fig = figure(13.5 if camera else 9.5, 3.9)
    axes = fig.subplots(1, 3 if camera else 2)
    if resolution is not None:
        from matplotlib.colors import BoundaryNorm, ListedColormap

        rows, cols = resolution
        pixels = np.asarray(plan.pixels)
        which = np.full(rows * cols, np.nan)
        log_mu = np.full(rows * cols, np.nan)
        for k, (_, queries, mu, _, _) in enumerate(parts):
            which[pixels[queries]] = k
            log_mu[pixels[queries]] = np.log10(mu)
        cmap = ListedColormap(colors).with_extremes(bad="0.85")
        axes[0].imshow(
            which.reshape(rows, cols),
            cmap=cmap,
            norm=BoundaryNorm(np.arange(len(parts) + 1) - 0.5, len(parts)),
            interpolation="nearest",
        )
        axes[0].set_title("part evaluating each pixel (colours: legend right; grey: no query)", fontsize=9)
        image = axes[1].imshow(
            log_mu.reshape(rows, cols), cmap=colormap("viridis").with_extremes(bad="0.85"), interpolation="nearest"
        )
        colorbar(fig, image, axes[1], "log₁₀ μ (facet size, scene length units)")
        axes[1].set_title("facet size each pixel resolves", fontsize=9)
        for ax in axes[:2]:
            ax.set_xlabel("pixel column")
            ax.set_ylabel("pixel row")
        histogram = axes[2]
    else:
        ax = axes[0]
        for (p, _, mu, u, _), color in zip(parts, colors):
            if u is None:
                ax.plot([], [], "o", color=color, label=_label(plan, p) + " (orientations, not drawn)")
            else:
                ax.plot(u, mu, "o", ms=2.5, color=color, alpha=0.6, label=_label(plan, p))
        ax.set_yscale("log")
        ax.set_xlabel("|u| = |m_s − m∞| (half-vector slope offset)")
        ax.set_ylabel("μ (facet size, scene length units)")
        ax.set_title("queries: where each part evaluates the lobe", fontsize=9)
        ax.legend(fontsize=7)
        histogram = axes[1]
    mus = np.concatenate([mu for _, _, mu, _, _ in parts])
    lo, hi = float(mus.min()), float(mus.max())
    bins = np.geomspace(lo / 1.05, hi * 1.05, 40) if hi > lo else np.array([lo / 1.1, hi * 1.1])
    for (p, _, mu, _, nodes), color in zip(parts, colors):
        histogram.hist(
            mu,
            bins=bins,
            color=color,
            histtype="step",
            lw=1.4,
            label=_label(plan, p) if camera else f"material {p.material}: {p.path}",
        )
        if p.path != "closed_form":  # the closed form is exact at every query's own μ: no nodes
            histogram.plot(
                nodes,
                np.full_like(nodes, 0.98),
                "|",
                color=color,
                ms=10,
                mew=1.2,
                transform=histogram.get_xaxis_transform(),
            )
    histogram.set_xscale("log")
    histogram.set_xlabel("μ (facet size, scene length units)")
    histogram.set_ylabel("queries")
    histogram.set_title(f"facet sizes queried; ticks: scale nodes (tol {plan.tol:.2g})", fontsize=9)
    histogram.legend(fontsize=7, loc="center right")
    for ax in axes:
        small_ticks(ax, integer=ax is histogram)
    return fig
