"""The report's data_vs_fit figure on lobes that fill a small part of their image (issue 31 item 9):
each row zoomed to where its lobe is, μ's unit in every title, and the statistics figure's μ with its
unit. The data are hand-built Gaussian lobe images (no fit is run: the figure reads the data and the
model's prediction at θ, so a FitResult at any θ of the model is enough); the lobe's mass inside the
window is measured on the image itself, not recomputed from the zoom rule."""

import equinox as eqx
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.transforms import Bbox

import brdfscale as bs
from brdfscale import fitting, plot
from tests import helpers


SIZE, EXTENT = 41, 1.0  # image pitch 0.05 slope
SCALES = (1e-6, 2e-6, 4e-6)


def _gaussian_image(mu: float, centre, sd: float, sigma: float = 0.02) -> bs.LobeImage:
    x = np.linspace(-EXTENT, EXTENT, SIZE)
    ux, uy = np.meshgrid(x, x)  # rows along u_y, columns along u_x (origin="lower")
    g = np.exp(-((ux - centre[0]) ** 2 + (uy - centre[1]) ** 2) / (2 * sd**2)) / (2 * np.pi * sd**2)
    return bs.LobeImage(
        mu=mu, incident=np.array([0.0, 0.0, 1.0]), extent=EXTENT, values=g, sigma=np.full(g.shape, sigma)
    )


def _problem_and_fit(images, unit="m"):
    model = fitting.ParametricModel()
    mset = bs.MeasurementSet(tuple(images), metadata={"unit": unit})
    problem = fitting.Problem(model, fitting.Dataset.from_measurements(mset))
    theta = np.asarray(model.theta_from(dict(amplitude=1.0, alpha_lobe=0.05, alpha_max=0.2, mu_c=1e-6, exponent=0.8)))
    result = helpers.fit_at(model.names, theta, np.eye(len(model.names)) * 1e-4, 3 * SIZE * SIZE)
    return problem, result


def _mass_inside(image: bs.LobeImage, xlim, ylim) -> float:
    x = np.linspace(-EXTENT, EXTENT, SIZE)
    inside = ((x >= xlim[0]) & (x <= xlim[1]))[None, :] & ((x >= ylim[0]) & (x <= ylim[1]))[:, None]
    return float(image.values[inside].sum() / image.values.sum())


@pytest.fixture(scope="module")
def narrow():
    """Three narrow lobes (rms 0.06–0.09 slope, 1.2–1.8 image pitches) on ±1 slope, off centre, one near an edge."""
    centres = [(0.4, -0.3), (0.0, 0.0), (-0.85, 0.6)]
    images = [_gaussian_image(mu, c, sd) for mu, c, sd in zip(SCALES, centres, (0.06, 0.08, 0.09))]
    return images, *_problem_and_fit(images)


def test_each_row_is_zoomed_to_where_its_lobe_is(narrow):
    images, problem, result = narrow
    fig = plot.fit(problem, result, unit="m")
    try:
        axes = [ax for ax in fig.axes if not hasattr(ax, "_colorbar")]
        assert len(axes) == 9
        for row, image in enumerate(images):
            for ax in axes[3 * row : 3 * row + 3]:
                xlim, ylim = ax.get_xlim(), ax.get_ylim()
                width, height = xlim[1] - xlim[0], ylim[1] - ylim[0]
                # a square window well inside the image: the lobe is not a dot in an empty panel
                assert width == pytest.approx(height) and 0.3 < width < 1.2, (row, xlim, ylim)
                # it holds the lobe: (almost) all of the image's light, measured on the image itself
                assert _mass_inside(image, xlim, ylim) > 0.995, (row, xlim, ylim)
                # and stays within the image (the lobe near the edge: the window is moved, not cut)
                assert -EXTENT - 1e-9 <= xlim[0] and xlim[1] <= EXTENT + 1e-9
                assert -EXTENT - 1e-9 <= ylim[0] and ylim[1] <= EXTENT + 1e-9
                title = ax.get_title()
                assert title.startswith(f"μ = {SCALES[row]:.4g} m") and title.endswith("(zoomed)"), title
    finally:
        plt.close(fig)


def test_a_lobe_that_fills_its_image_is_not_zoomed():
    wide = [_gaussian_image(mu, (0.0, 0.0), 0.3) for mu in SCALES]
    problem, result = _problem_and_fit(wide)
    fig = plot.fit(problem, result)
    try:
        for ax in (ax for ax in fig.axes if not hasattr(ax, "_colorbar")):
            whole = pytest.approx((-EXTENT, EXTENT))
            assert ax.get_xlim() == whole and ax.get_ylim() == whole
            assert "zoomed" not in ax.get_title() and " px: " in ax.get_title(), ax.get_title()  # no unit given: px
    finally:
        plt.close(fig)


@pytest.mark.parametrize("gain", [1.0, 3e5])
def test_the_fixed_layout_keeps_every_panels_text_inside_the_figure_and_apart(gain):
    """plot_fit places its panels on a fixed grid (fitting._plot._fixed_grid, not constrained
    layout): drawn, each panel with its colour bar — titles, tick labels, axis and colour-bar
    labels — lies inside the figure and overlaps no other panel's, also with six-digit lobe values
    (wide colour-bar tick labels)."""
    images = [_gaussian_image(mu, (0.0, 0.0), sd) for mu, sd in zip(SCALES, (0.06, 0.08, 0.09))]
    images = [
        bs.LobeImage(mu=i.mu, incident=i.incident, extent=i.extent, values=i.values * gain, sigma=i.sigma)
        for i in images
    ]
    problem, result = _problem_and_fit(images)
    fig = plot.fit(problem, result, unit="m")
    try:
        canvas = FigureCanvasAgg(fig)  # what savefig(…png) draws with
        canvas.draw()
        renderer = canvas.get_renderer()
        panels = [ax for ax in fig.axes if not hasattr(ax, "_colorbar")]
        bars = [ax for ax in fig.axes if hasattr(ax, "_colorbar")]
        assert len(panels) == len(bars) == 9
        boxes = []
        for ax, bar in zip(panels, bars):  # fig.axes: each panel, then its colour bar
            assert bar._colorbar.mappable is ax.images[0]
            box = Bbox.union([ax.get_tightbbox(renderer), bar.get_tightbbox(renderer)])
            assert fig.bbox.contains(box.x0, box.y0) and fig.bbox.contains(box.x1, box.y1), (ax.get_title(), box)
            boxes.append(box)
        for i, a in enumerate(boxes):
            for j, b in enumerate(boxes[:i]):
                assert not a.overlaps(b), (panels[i].get_title(), panels[j].get_title(), a, b)
    finally:
        plt.close(fig)


def test_the_statistics_figure_names_mus_unit(narrow):
    _, problem, result = narrow
    fig = plot.recovered_statistics(problem, result, unit="m")
    try:
        texts = [fig.axes[0].get_title()] + [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
        mus = [t for t in texts if "μ" in t]
        assert mus and all(t.count(" m") >= 1 for t in mus), texts
    finally:
        plt.close(fig)


def _residual_panels(fig):
    """(axes, image) of every residual panel (the third of each row)."""
    return [(ax, ax.images[0]) for ax in fig.axes if ax.images and not hasattr(ax, "_colorbar")][2::3]


def _shown(ax, image) -> np.ndarray:
    """The |values| of ``image`` inside the axes' limits."""
    x = np.linspace(-EXTENT, EXTENT, SIZE)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    inside = ((x >= x0) & (x <= x1))[None, :] & ((y0 <= x) & (x <= y1))[:, None]
    return np.abs(np.asarray(image.get_array()))[inside]


def test_the_residual_colour_scale_widens_for_a_poor_fit_only(narrow):
    """The model at θ predicts a lobe unlike the data (a poor fit, residuals of hundreds of σ): the
    residual panels' range is wider than ±4 and saturates at most 1 % of the pixels shown (plus
    rounding up); data equal to the prediction up to noise within ±1 σ keep ±4."""
    images, problem, result = narrow
    fig = plot.fit(problem, result)
    try:
        for ax, image in _residual_panels(fig):
            low, high = image.get_clim()
            shown = _shown(ax, image)
            assert low == -high and high > 4 and shown.max() > 4, (high, shown.max())
            assert np.mean(shown > high) <= 0.01, (high, np.quantile(shown, 0.99))
    finally:
        plt.close(fig)
    predicted = np.asarray(eqx.filter_jit(problem.model.predict)(jnp.asarray(result.theta), problem.data))
    rng = np.random.default_rng(3)
    exact = [
        bs.LobeImage(
            mu=image.mu,
            incident=image.incident,
            extent=EXTENT,
            values=problem.data.image(i, predicted[i]) + rng.uniform(-1, 1, (SIZE, SIZE)),
            sigma=np.ones((SIZE, SIZE)),
        )
        for i, image in enumerate(images)
    ]
    problem2, result2 = _problem_and_fit(exact)
    fig = plot.fit(problem2, result2)
    try:
        assert all(image.get_clim() == (-4.0, 4.0) for _, image in _residual_panels(fig))
    finally:
        plt.close(fig)


def test_the_statistics_of_an_anisotropic_fit_by_direction():
    """AnisotropicModel at known ΔΣ (tests/helpers.py ANISO_TRUTH): the ratio panel draws
    exp(−½ W² ΔΣ_xx) along W_x (solid) and exp(−½ W² ΔΣ_yy) along W_y (dashed) — the closed form of a
    Gaussian change of the lobe, not the direction average — and the ΔΣ panel the entries of
    fit.covariance_differences with their standard errors (an entry without one hollow)."""
    data = helpers.anisotropic_dataset(0)
    model = fitting.AnisotropicModel(3)
    truth = helpers.ANISO_TRUTH
    differences = helpers.anisotropic_differences()
    theta = np.asarray(helpers.anisotropic_theta(model, truth["amplitude"], truth["C0"], truth["mean"], differences))
    entries = [
        {
            "mu0": helpers.ANISO_SCALES[0],
            "mu": mu,
            "value": d.tolist(),
            "std": None if k == 2 else (0.1 * np.abs(d) + 1e-4).tolist(),
        }
        for k, (mu, d) in enumerate(zip(helpers.ANISO_SCALES, differences), start=0)
        if k > 0
    ]
    n = len(model.names)
    result = helpers.fit_at(
        model.names,
        theta,
        np.eye(n) * 1e-18,  # the draws sit at θ: the bands' medians are the curves at θ
        data.values.size,
        solver="lm_normal",
        covariance_differences=entries,
    )
    fig = plot.recovered_statistics(fitting.Problem(model, data), result, unit="m")
    try:
        ratio, delta = fig.axes[:2]
        drawn = [line for line in ratio.get_lines() if len(line.get_xdata()) > 1]
        assert len(drawn) == 4  # two coarser scales × two directions
        for j, line in enumerate(drawn):
            k, axis = 1 + j // 2, j % 2
            W = np.asarray(line.get_xdata())
            expected = np.exp(-0.5 * W**2 * differences[k][axis, axis])
            assert line.get_linestyle() == ("-" if axis == 0 else "--")
            np.testing.assert_allclose(line.get_ydata(), expected, rtol=1e-6, atol=1e-9)
        assert "W_x" in ratio.get_title() and "m" in ratio.get_title()
        bars = delta.containers
        assert len(bars) == 3
        for container, (a, b) in zip(bars, ((0, 0), (1, 1), (0, 1))):
            np.testing.assert_allclose(container.lines[0].get_ydata(), [differences[1][a, b]])
        hollow = [line for line in delta.get_lines() if line.get_markerfacecolor() == "none" and len(line.get_xdata())]
        assert len(hollow) == 3 and all(line.get_xdata()[0] == helpers.ANISO_SCALES[2] for line in hollow)
        assert "(m)" in delta.get_xlabel()
    finally:
        plt.close(fig)


def test_a_scale_laws_legend_names_mus_length_units():
    """A scale law carries no unit: plot.statistics' legend says μ is in its length units."""
    from brdfscale import stats

    law = stats.ScaledFamily(stats.Beckmann, stats.WidthLaw(0.2, 1.0, 0.8))
    fig = plot.statistics(law, mu=[0.5, 2.0], size=33)
    try:
        labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert labels == ["μ = 0.5 (length units)", "μ = 2 (length units)"], labels
    finally:
        plt.close(fig)
