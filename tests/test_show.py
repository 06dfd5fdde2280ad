"""Objects that show themselves (issue 17): compact reprs and HTML summaries of every public
object, also under jax.jit / eval_shape / vmap; the one-call figures of brdfscale.plot (axes,
labels, pyplot's figure list untouched); imports that leave matplotlib and float64 alone; the
progress bar's mode and its switches. Small sizes throughout: the file runs in seconds."""

import dataclasses
import html.parser
import io
import sys
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.figure import Figure

import brdfscale as bs
from brdfscale import fitting, InvalidInputError, lobes, plot, scene, show, stats, synth
from brdfscale._evolve import EvolvedDensity


TRUTH = dict(amplitude=0.8, alpha_lobe=0.05, alpha_max=0.2, mu_c=1.0, exponent=0.8)
LAW = stats.ScaledFamily(stats.Beckmann, stats.WidthLaw(0.2, 1.0, 0.8))
FIELD = synth.named_surface("gaussian", size=64, seed=0)
FACETS = synth.facet_statistics(FIELD, [1.0, 4.0, 16.0], bins=33)


# -- fixtures: one of everything, built without fits or compiled solves where possible -------


@pytest.fixture(scope="module")
def fitted():
    """A problem, a FitResult at the truth with a Laplace covariance, and a 4000-draw SampleResult.

    The results are built as fitting.fit/sample would return them (their fields), not by running
    the solver or the sampler: what is tested is how they show themselves."""
    model = fitting.ParametricModel()
    mset = fitting.simulate(model, TRUTH, (0.5, 2.0, 8.0), size=9, extent=0.3, noise=0.05, seed=1)
    problem = fitting.Problem(model, fitting.Dataset.from_measurements(mset))
    names = model.names
    theta = model.theta_from(TRUTH)
    cov = np.diag([1e-4, 2e-4, 3e-4, 2e-3, 1e-3])
    std = {"amplitude": 0.008, "alpha_lobe": 0.0007, "alpha_max": 0.0035, "mu_c": None, "exponent": None}
    quantiles = {k: (None if v is None else [TRUTH[k] - 1.6 * v, TRUTH[k], TRUTH[k] + 1.6 * v]) for k, v in std.items()}
    result = fitting.FitResult(
        names=names,
        theta=theta,
        covariance=cov,
        chi2=231.5,
        n_data=243,
        status="converged",
        starts=[{"chi2": 231.5, "result": "successful", "steps": 7, "at_best": True}],
        estimates=dict(TRUTH),
        std=std,
        quantiles=quantiles,
        eigenvalues=np.array([1e-13, 3e2, 1e3, 3e3, 1e4]),
        undetermined=[{"combination": "0.77·log exponent + 0.64·log mu_c", "fisher_eigenvalue": 1e-13, "std": None}],
        notes=list(model.identifiability_notes),
        solver="lm",
        at_bounds=[],
        ratios={
            "S(μ0)/S(μ1) @ |W|=4.2": {
                "estimate": 0.913,
                "std": 0.004,
                "quantiles_5_50_95": [0.906, 0.913, 0.92],
                "mu0": 0.5,
                "mu": 2.0,
                "W": 4.2,
            }
        },
        combinations=[{"combination": "0.84·log alpha_max + 0.52·log alpha_lobe", "value": -4.1, "std": 0.01}],
    )
    rng = np.random.default_rng(0)
    chain = theta + 0.01 * rng.standard_normal((300, 16, len(names)))
    samples = fitting.SampleResult(
        names=names,
        chain=chain,
        log_prob=-0.5 * rng.chisquare(5, (300, 16)),
        burn=50,
        tau=np.full(len(names), 12.0),
        ess=np.full(len(names), 330.0),
        tau_reliable=False,
        acceptance=0.41,
    )
    assert samples.samples.shape == (4000, len(names))
    return mset, problem, result, samples


@pytest.fixture(scope="module")
def plans():
    """A camera plan with two materials (closed form), and the same plan without its camera."""
    mat = scene.Material(lobes.Beckmann(0.05), 0.1, LAW)
    other = scene.Material(lobes.Beckmann(0.08, amplitude=0.5), 0.1, LAW)
    cam = scene.Camera(height=2.0, pitch=0.3, fov=0.8, resolution=(8, 12))
    light = np.array([0.3, 0.0, np.sqrt(1 - 0.09)])
    camera = scene.plan(
        scene.camera_scene([mat, other], cam, light, 1e-3, texture=lambda xy: (xy[:, 1] > 0).astype(int))
    )
    return camera, dataclasses.replace(camera, pixels=None, resolution=None)  # the same queries, no camera


def _big_measurement_set(n=512):
    rng = np.random.default_rng(0)
    values = rng.random((n, n))
    mask = np.ones((n, n), bool)
    mask[:3] = False
    images = tuple(
        bs.LobeImage(
            mu=mu, incident=np.array([0.0, 0.0, 1.0]), extent=0.4, values=values, sigma=np.full((n, n), 0.1), mask=mask
        )
        for mu in (1.0, 2.0, 4.0)
    )
    return bs.MeasurementSet(images, metadata={"truth": {"params": TRUTH}, "source": "test"})


@pytest.fixture(scope="module")
def objects(fitted, plans):
    """One object of every class that shows itself, by name."""
    return _everything(fitted, plans)


def _everything(fitted, plans):
    mset, problem, result, samples = fitted
    s0, s1 = LAW.at(1.0), LAW.at(4.0)
    spectral = lobes.Lobe(
        EvolvedDensity(stats.GGX(0.05), stats.GGX(0.2), stats.GGX(0.1), 0.0, bs.Radial(nodes=64, cutoff=100.0), 1e-6)
    )
    big = _big_measurement_set()
    hist = stats.SlopeHistogram(0.3, 17)
    hist.add(np.zeros(5), np.zeros(5))
    return {
        "Beckmann lobe": lobes.Beckmann(0.1),
        "GGX lobe": lobes.GGX(alpha_x=0.1, alpha_y=0.2, amplitude=2.0),
        "Mirror": lobes.Mirror(0.5),
        "Tabulated lobe": lobes.Tabulated(jnp.ones((33, 33)), extent=0.3),
        "Lobe": lobes.Lobe(stats.Disk(0.2), 3.0),
        "evolved (closed form)": bs.evolve(lobes.Beckmann(0.05), s0, s1),
        "evolved (radial)": spectral,
        "Delta": stats.Delta(mean=[0.01, 0.0]),
        "Gaussian": stats.Gaussian(cov=[[0.01, 0.002], [0.002, 0.02]], mean=[0.1, 0.0]),
        "GGX": stats.GGX(0.2),
        "Disk": stats.Disk(0.1),
        "Mixture": stats.Mixture([1.0, 2.0, 3.0, 4.0, 5.0], [stats.Beckmann(0.1 * k) for k in range(1, 6)]),
        "Tabulated": stats.Tabulated(jnp.ones((65, 65)), extent=0.5),
        "SlopeHistogram": hist,
        "ScaledFamily": LAW,
        "GaussianSurface": stats.GaussianSurface(stats.GaussianCorrelation(0.1, 2.0)),
        "method": spectral.shape.discretisation,
        "LobeImage": big.images[0],
        "MeasurementSet": big,
        "camera plan": plans[0],
        "plan": plans[1],
        "Scene": scene.Scene(
            (scene.Material(lobes.Beckmann(0.05), 0.1, LAW),), scene.Queries([0, 0, 1.0], [0, 0, 1.0], 1.0), 1e-3
        ),
        "Dataset": problem.data,
        "Problem": problem,
        "FitResult": result,
        "SampleResult": samples,
        "small MeasurementSet": mset,
    }


def _compact(text: str, what: str) -> None:
    assert len(text.splitlines()) <= show.MAX_LINES and len(text) <= show.MAX_CHARS, (what, text)
    assert "array(" not in text and "[[" not in text and "\n\n" not in text, (what, text)


# -- reprs --------------------------------------------------------------------------------


def test_every_repr_is_a_few_lines_and_no_array_dump(objects):
    for what, obj in objects.items():
        text = repr(obj)
        _compact(text, what)
        assert text.startswith(type(obj).__name__ + "("), (what, text)
    assert repr(objects["Beckmann lobe"]) == "Beckmann(alpha=0.1, amplitude=1)"
    assert repr(objects["GGX lobe"]) == "GGX(alpha=(0.1, 0.2), amplitude=2)"
    assert "values=f64[512,512]" in repr(objects["LobeImage"]) and "1536 of 262144 px masked" in repr(
        objects["LobeImage"]
    )
    assert "scales=(1, 2, 4)" in repr(objects["MeasurementSet"]) and "512×512" in repr(objects["MeasurementSet"])
    assert "chain=f64[300,16,5]" in repr(objects["SampleResult"]) and "draws=4000" in repr(objects["SampleResult"])
    fit_text = repr(objects["FitResult"])
    assert "amplitude=0.8 ± 0.008" in fit_text and "mu_c=1 (undetermined)" in fit_text and "converged" in fit_text
    assert "path=radial" in repr(objects["evolved (radial)"]) and "nodes=64" in repr(objects["evolved (radial)"])
    assert "sigma=(0.1, 0.1414), rho=0.1414, mean=(0.1, 0)" in repr(objects["Gaussian"])
    assert "camera=8×12 px" in repr(objects["camera plan"]) and "closed_form" in repr(objects["camera plan"])
    # a long summary is cut with … rather than running past its limits
    assert repr(objects["Mixture"]).count("Gaussian") <= 4


def test_reprs_under_jit_eval_shape_and_vmap(fitted, plans):
    _, problem, _, _ = fitted
    seen = {}

    @jax.jit
    def traced(a):
        seen["lobe"] = repr(lobes.GGX(alpha_x=a, alpha_y=2 * a, amplitude=a))
        seen["gaussian"] = repr(stats.Gaussian(cov=jnp.eye(2) * a))
        seen["mixture"] = repr(stats.Mixture(jnp.stack([a, 1 - a]), [stats.Beckmann(a), stats.Delta()]))
        seen["evolved"] = repr(
            bs.evolve(lobes.Beckmann(a), stats.Beckmann(2 * a), stats.Beckmann(a), method="closed_form")
        )
        print(lobes.Beckmann(a))  # printing inside jit must not fail either
        return a

    traced(0.1)
    for what, text in seen.items():
        _compact(text, what)
        assert "f64[]" in text or "f32[]" in text, (what, text)

    @eqx.filter_jit
    def with_modules(data, plan):
        seen["dataset"], seen["plan"] = repr(data), repr(plan)
        return data.values.sum()

    with_modules(problem.data, plans[1])
    assert "scales=f64[3]" in seen["dataset"] and "valid_pixels" not in seen["dataset"]
    assert seen["plan"] == repr(plans[1])  # a plan shows only what is static

    abstract = jax.eval_shape(lambda: bs.evolve(lobes.Beckmann(0.05), LAW.at(1.0), LAW.at(4.0)))
    assert "f64[]" in repr(abstract) and abstract._repr_html_().startswith("<table")
    batch = jax.vmap(lambda a: lobes.GGX(a, amplitude=2 * a))(jnp.linspace(0.1, 0.2, 5))
    assert repr(batch) == "GGX(alpha=f64[5], amplitude=f64[5])"
    pair = jax.vmap(lambda a: stats.Beckmann(a))(jnp.array([0.1, 0.2]))
    assert repr(pair) == "Gaussian(sigma=(0.07071, 0.1414), alpha=(0.1, 0.2))"


class _Parser(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.open, self.tables, self.text = [], 0, []

    def handle_starttag(self, tag, attrs):
        if tag not in ("br",):
            self.open.append(tag)
        self.tables += tag == "table"

    def handle_endtag(self, tag):
        assert self.open and self.open[-1] == tag, (self.open, tag)
        self.open.pop()

    def handle_data(self, data):
        self.text.append(data)


def _parse(markup: str) -> _Parser:
    parser = _Parser()
    parser.feed(markup)
    parser.close()
    assert not parser.open, parser.open
    return parser


def test_html_summaries_parse_and_hold_the_key_numbers(objects):
    for what, obj in objects.items():
        parsed = _parse(obj._repr_html_())
        assert parsed.tables >= 1 and type(obj).__name__ in parsed.text, what
    fit_html = _parse(objects["FitResult"]._repr_html_())
    assert fit_html.tables == 5  # summary, parameters, ratios, determined and undetermined combinations
    text = " ".join(fit_html.text)
    for token in (
        "estimate",
        "std",
        "5 %",
        "95 %",
        "0.8",
        "0.0007",
        "0.77·log exponent",
        "S(μ0)/S(μ1) @ |W|=4.2",
        "0.913",
        "0.84·log alpha_max",
    ):
        assert token in text, token
    mset_html = _parse(objects["MeasurementSet"]._repr_html_())
    assert mset_html.tables == 2 and "512×512" in " ".join(mset_html.text)
    assert "τ (steps)" in " ".join(_parse(objects["SampleResult"]._repr_html_()).text)
    plan_text = " ".join(_parse(objects["camera plan"]._repr_html_()).text)
    assert "closed_form" in plan_text and "predicted error" in plan_text
    assert "0.1" in " ".join(_parse(objects["Beckmann lobe"]._repr_html_()).text)


# -- figures ------------------------------------------------------------------------------


def _check_figure(fig, axes: int, what: str, unlabelled: int = 0, draw: bool = False):
    """``axes`` axes, every visible one labelled (``unlabelled``: inner panels of a grid whose
    labels are on its edges); ``draw``: render it too (costs a second on a busy machine)."""
    assert isinstance(fig, Figure), what
    assert len(fig.axes) == axes, (what, len(fig.axes))
    visible = [ax for ax in fig.axes if ax.get_visible() and ax.axison]
    bare = [ax for ax in visible if not (ax.get_xlabel() or ax.get_ylabel())]
    assert len(bare) == unlabelled, (what, [ax.get_title() for ax in bare])
    for ax in visible:
        if ax.get_images():  # an image says what it shows and where
            assert ax.get_title() and ax.get_xlabel() and ax.get_ylabel(), what
    if draw:
        fig.savefig(io.BytesIO(), format="png", dpi=30)


def test_plot_functions_return_figures_outside_pyplot(fitted, plans):
    mset, problem, result, samples = fitted
    before = plt.get_fignums()
    incident = [0.3, 0.0, np.sqrt(1 - 0.09)]
    checks = [
        (plot.lobe(lobes.Beckmann(0.1), size=17), 3, "lobe"),
        (plot.lobe(lobes.Beckmann(0.1), incident=incident, size=17, log=True), 5, "lobe + BRDF"),
        (lobes.Beckmann(alpha_x=0.1, alpha_y=0.05).plot(size=17), 3, "lobe.plot (anisotropic)"),
        (plot.statistics(LAW, mu=[0.5, 2.0], size=33), 2, "statistics of a law"),
        (
            plot.statistics(
                [stats.Delta(), stats.Beckmann(alpha_x=0.1, alpha_y=0.2)], labels=["flat", "rough"], size=33
            ),
            2,
            "list",
        ),
        (LAW.plot(mu=[1.0], size=33), 2, "law.plot"),
        (stats.Beckmann(0.1).plot(size=33), 2, "density.plot"),
        (plot.measurements(mset), 12, "measurements"),
        (plot.facet_statistics(FACETS, field=FIELD), 3, "facet statistics"),
        (mset.plot(images=[0]), 4, "mset.plot"),
        (mset.images[1].plot(), 4, "image.plot"),
        (plot.plan(plans[0]), 4, "camera plan"),
        (plans[1].plot(), 2, "plan"),
        (plot.fit(problem, result), 18, "fit"),
        (result.plot(problem), 18, "FitResult.plot"),
        (plot.recovered_statistics(problem, result, truth=TRUTH), 2, "recovered statistics"),
        (plot.recovered_statistics(problem, result, samples), 2, "recovered statistics, MCMC"),
        # the corner package's grid of the determined quantities (3 here: mu_c and exponent are left out,
        # undetermined), labels on its edges
        (plot.corner(problem, result, samples, truth=TRUTH), 9, "corner", 2),
        (plot.chains(samples), 6, "chains"),
        (samples.plot(coordinates=2), 3, "samples.plot"),
    ]
    for fig, axes, what, *unlabelled in checks:
        _check_figure(fig, axes, what, *unlabelled, draw=what == "lobe + BRDF")
    assert plt.get_fignums() == before
    # the colour bars say what they show
    assert [ax.get_ylabel() for ax in checks[0][0].axes if hasattr(ax, "_colorbar")] == ["A·g(u) (per unit slope²)"]
    assert any("1/sr" in ax.get_ylabel() for ax in checks[1][0].axes)
    assert checks[4][0].axes[0].get_legend().get_texts()[0].get_text().startswith("flat: no pointwise density")


def test_plot_functions_refuse_what_they_cannot_draw(fitted):
    mset, problem, result, _ = fitted
    batch = jax.vmap(lambda a: lobes.Beckmann(a))(jnp.array([0.1, 0.2]))
    bad = [
        (lambda: plot.lobe("lobe"), "brdfscale.lobes lobe"),
        (lambda: plot.lobe(lobes.Mirror()), "point mass"),
        (lambda: plot.lobe(batch), "batch of shape"),
        (lambda: plot.lobe(lobes.Beckmann(0.1), incident=[1.0, 0.0, 0.0]), "incident"),
        (lambda: plot.lobe(lobes.Beckmann(0.1), extent=-1), "extent"),
        (lambda: plot.statistics(LAW), "mu="),
        (lambda: plot.statistics(stats.Disk(0.1), mu=[1.0]), "scale law"),
        (lambda: plot.statistics([stats.Disk(0.1)], labels=["a", "b"]), "labels"),
        (lambda: plot.measurements(mset, images=[7]), "image indices"),
        (lambda: plot.measurements([1, 2]), "MeasurementSet"),
        (lambda: plot.plan(42), "Plan"),
        (lambda: plot.chains(result), "SampleResult"),
        (lambda: plot.facet_statistics([1, 2]), "FacetStatistics"),
        (lambda: plot.facet_statistics(FACETS, field="f"), "HeightField"),
    ]
    for call, match in bad:
        with pytest.raises(InvalidInputError, match=match):
            call()
    seen = []
    jax.jit(lambda a: seen.append(pytest.raises(InvalidInputError, plot.lobe, lobes.Beckmann(a))) or a)(0.1)
    assert "traced" in str(seen[0].value)


# -- progress bars -------------------------------------------------------------------------


@pytest.mark.wrong_types
def test_plot_fit_refuses_what_is_no_fit_result(fitted):
    _, problem, _, _ = fitted
    with pytest.raises(InvalidInputError, match="FitResult"):
        plot.fit(problem, "fit")


@pytest.mark.wrong_types
def test_plot_corner_refuses_a_truth_that_is_no_dict(fitted):
    _, problem, result, _ = fitted
    with pytest.raises(InvalidInputError, match="truth"):
        plot.corner(problem, result, truth="x")


def test_progress_bar_picks_text_outside_jupyter_and_honours_the_switches(monkeypatch, fitted):
    import tqdm.std

    from brdfscale import _show

    monkeypatch.delenv(show.PROGRESS_VARIABLE, raising=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "IProgress not found" or any other warning
        assert show.progress_mode() == "text"
        with show.progress_bar(total=3, desc="t", file=io.StringIO()) as bar:
            assert type(bar) is tqdm.std.tqdm and not bar.disable
            bar.update(3)
        assert list(show.progress_bar(range(3), enabled=False)) == [0, 1, 2]
        # a Jupyter kernel without ipywidgets: the text bar, silently
        fake_ipython = type(sys)("IPython")
        fake_ipython.get_ipython = lambda: type("ZMQInteractiveShell", (), {})()
        monkeypatch.setitem(sys.modules, "ipykernel", type(sys)("ipykernel"))
        monkeypatch.setitem(sys.modules, "IPython", fake_ipython)
        assert _show._in_jupyter_kernel()
        monkeypatch.setattr(_show, "_notebook_bar", lambda: None)
        assert show.progress_mode() == "text"
        # … and with them, the notebook bar, unless BRDFSCALE_PROGRESS=text
        monkeypatch.setattr(_show, "_notebook_bar", lambda: tqdm.std.tqdm)
        assert show.progress_mode() == "notebook"
        monkeypatch.setenv(show.PROGRESS_VARIABLE, "text")
        assert show.progress_mode() == "text"
    for off in ("0", "false", "OFF"):
        monkeypatch.setenv(show.PROGRESS_VARIABLE, off)
        assert show.progress_mode() == "off"
        with show.progress_bar(total=2) as bar:
            assert bar.disable
    monkeypatch.setenv(show.PROGRESS_VARIABLE, "maybe")
    with pytest.raises(InvalidInputError, match="BRDFSCALE_PROGRESS is 'maybe'"):
        show.progress_bar(total=1)
    _, problem, result, _ = fitted
    with pytest.raises(InvalidInputError, match="BRDFSCALE_PROGRESS"):
        fitting.sample(problem, result, steps=2)


@pytest.mark.wrong_types
def test_progress_switches_that_are_not_booleans_are_refused(monkeypatch, fitted):
    _, problem, result, _ = fitted
    monkeypatch.delenv(show.PROGRESS_VARIABLE, raising=False)
    with pytest.raises(InvalidInputError, match="progress"):
        fitting.sample(problem, result, steps=2, progress="yes")
    with pytest.raises(InvalidInputError, match="progress must be True or False"):
        show.progress_bar(total=1, enabled=1)


def test_chains_plot_names_the_samplers_trajectories():
    """plot.chains' title says what the trajectories are: NUTS/HMC chains, or emcee's
    ensembles of walkers (one colour per independent chain)."""
    from brdfscale import fitting

    rng = np.random.default_rng(0)
    common = dict(names=("log a", "log b"), burn=5, tau=np.ones(2), ess=np.ones(2), tau_reliable=True, acceptance=0.8)
    hmc = fitting.SampleResult(
        chain=rng.normal(size=(20, 4, 2)), log_prob=rng.normal(size=(20, 4)), sampler="hmc", chains=4, **common
    )
    ens = fitting.SampleResult(
        chain=rng.normal(size=(20, 16, 2)), log_prob=rng.normal(size=(20, 16)), sampler="emcee", chains=4, **common
    )
    assert plot.chains(hmc).axes[0].get_title().startswith("4 HMC chains, 20 steps; warm-up 5")
    fig = plot.chains(ens)
    assert fig.axes[0].get_title().startswith("4 × 4 walkers, 20 steps; burn-in 5")
    assert (
        len(
            {
                tuple(line.get_color()) if not isinstance(line.get_color(), str) else line.get_color()
                for line in fig.axes[1].get_lines()[:-1]
            }
        )
        == 4
    )  # one colour per ensemble (the last line: burn-in)
