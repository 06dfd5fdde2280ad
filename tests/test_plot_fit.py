"""The report's data_vs_fit figure on lobes that fill a small part of their image (issue 31 item 9):
each row zoomed to where its lobe is, μ's unit in every title, and the statistics figure's μ with its
unit. The data are hand-built Gaussian lobe images (no fit is run: the figure reads the data and the
model's prediction at θ, so a FitResult at any θ of the model is enough); the lobe's mass inside the
window is measured on the image itself, not recomputed from the zoom rule."""

import matplotlib.pyplot as plt
import numpy as np
import pytest

import brdfscale as bs
from brdfscale import fitting, plot


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
    n = len(model.names)
    result = fitting.FitResult(
        names=model.names,
        theta=theta,
        covariance=np.eye(n) * 1e-4,
        chi2=1.0,
        n_data=3 * SIZE * SIZE,
        status="converged",
        starts=[],
        estimates={},
        std={},
        quantiles={},
        eigenvalues=np.ones(n),
        undetermined=[],
        notes=[],
        solver="lm",
        at_bounds=[],
        ratios={},
        combinations=[],
    )
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


def test_the_statistics_figure_names_mus_unit(narrow):
    _, problem, result = narrow
    fig = plot.recovered_statistics(problem, result, unit="m")
    try:
        texts = [fig.axes[0].get_title()] + [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
        mus = [t for t in texts if "μ" in t]
        assert mus and all(t.count(" m") >= 1 for t in mus), texts
    finally:
        plt.close(fig)
