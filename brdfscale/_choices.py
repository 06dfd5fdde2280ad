"""The choices of a fit and the defaults of its options: one table read by :mod:`brdfscale.fitting`,
:mod:`brdfscale.library` and the ``brdfscale`` command (its ``--help`` included).

Importing it imports neither JAX nor NumPy, so the command's help starts without them.

* :data:`SOLVERS`, :data:`SAMPLERS`, :data:`MODELS`, :data:`FAMILIES`, :data:`LAWS`, :data:`SHAPES`, :data:`INCREMENTS`,
  :data:`MASKING` — the names a fit accepts, each with a one-line description and the default (:class:`Choices`);
* :data:`INSTRUMENTS`, :data:`WEIGHTINGS`, :data:`MICRO_FACETS` — ``brdfscale synth``'s instruments, pixel-facet
  weightings (also ``synth.gonioreflectometer``'s) and rough facets; :data:`BINNINGS`, :data:`MESHES`,
  :data:`EXECUTORS` — the ray-traced instrument's (:mod:`brdfscale.instrument`) detector binnings, meshes and
  executors (the last also :func:`brdfscale.library.fit_library`'s);
* :data:`FORMS`, :data:`OUTPUTS`, :data:`FOOTPRINTS` — :mod:`brdfscale.render`'s material forms and its
  integrator's outputs and footprints;
* :class:`FitDefaults`, :class:`SampleDefaults`, :class:`ModelDefaults` — the defaults of the
  options of ``fitting.fit``/``fit_many``, ``fitting.sample``/``sample_many`` and of the models;
  their instances :data:`FIT`, :data:`SAMPLE`, :data:`MODEL` are what the functions'
  signatures, :class:`brdfscale.library.FitSpec` and the command's options read (the options
  themselves are checked where they are used: ``fitting``'s own option classes).

tests/test_choices.py checks that every name here is accepted by fitting and by the command,
and that the command's defaults and the library's signatures equal these. The public names are
:mod:`brdfscale.choices`'s ``__all__`` (the one list; tests/test_choices.py checks it holds every table here).
"""

import dataclasses

from ._errors import InvalidInputError


@dataclasses.dataclass(frozen=True)
class Choice:
    """One accepted name and what it selects, in one line."""

    name: str
    summary: str


@dataclasses.dataclass(frozen=True)
class Choices:
    """The names one argument accepts (``what``: the argument's name), in the order the help lists
    them, and the default among them."""

    what: str
    items: tuple[Choice, ...]
    default: str

    def __post_init__(self):
        if len(set(self.names)) != len(self.items) or self.default not in self.names:
            raise ValueError(f"{self.what}: names must be unique and include the default {self.default!r}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(item.name for item in self.items)

    def __contains__(self, name) -> bool:
        return isinstance(name, str) and name in self.names

    def __iter__(self):
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.items)

    def summary(self, name: str) -> str:
        """The one-line description of ``name``."""
        return {item.name: item.summary for item in self.items}[self.check(name)]

    def check(self, name) -> str:
        """``name`` if it is one of these; :class:`brdfscale.InvalidInputError` naming the argument otherwise."""
        if name not in self:
            raise InvalidInputError(f"{self.what} must be one of {', '.join(map(repr, self.names))}; got {name!r}.")
        return name

    def help(self) -> str:
        """The choices in words: ``name (default): summary; name: summary; …``."""
        return "; ".join(
            f"{item.name}{' (default)' if item.name == self.default else ''}: {item.summary}" for item in self.items
        )


SOLVERS = Choices(
    "solver",
    (
        Choice(
            "auto",
            "the model's own choice: lm_normal for the anisotropic models (many rows per parameter), "
            "gauss_newton_edm for the anisotropic non-parametric one, lm for the others (the model's preferred_solver)",
        ),
        Choice("lm", "Levenberg–Marquardt (optimistix.LevenbergMarquardt)"),
        Choice(
            "lm_normal",
            "Levenberg–Marquardt whose steps solve the normal equations by Cholesky (lineax.Normal): "
            "much faster when the rows far outnumber the parameters, e.g. the anisotropic models on 65² px "
            "images; it squares the condition number",
        ),
        Choice("gauss_newton", "Gauss–Newton (optimistix.GaussNewton)"),
        Choice(
            "gauss_newton_edm",
            "Gauss–Newton with a line search, the directions the data do not determine left out, stopped when "
            "the expected distance to the minimum is below 1e-3 of the reduced χ² (fitting._gauss_newton): "
            "for many parameters with undetermined ones, e.g. the anisotropic non-parametric model",
        ),
        Choice("dogleg", "Powell's dogleg (optimistix.Dogleg)"),
        Choice("bfgs", "BFGS, a minimiser of ½‖r‖² (optimistix.BFGS)"),
    ),
    default="auto",
)

SAMPLERS = Choices(
    "sampler",
    (
        Choice("nuts", "BlackJAX NUTS, Laplace-preconditioned (fitting.NUTS)"),
        Choice("hmc", "BlackJAX HMC of fixed trajectory length, Laplace-preconditioned (fitting.HMC)"),
        Choice("emcee", "emcee's affine-invariant ensembles (fitting.Emcee)"),
        Choice(
            "imh",
            "independence Metropolis–Hastings from the Laplace approximation, one log-density per step (fitting.IMH): "
            "fast where that approximation is close (an adequate fit), stuck where it is not",
        ),
        Choice(
            "auto",
            "imh where the Pareto k̂ of its proposal's importance weights says the Laplace approximation covers the "
            "posterior, nuts otherwise (fitting.Auto)",
        ),
    ),
    default="auto",
)

MODELS = Choices(
    "model",
    (
        Choice(
            "anisotropic",
            "a base lobe of full covariance (any orientation, --shape gaussian, ggx or student_t) and free "
            "centre, and the covariance difference ΔΣ(μ0, μk), a full 2 × 2 matrix per scale "
            "(fitting.AnisotropicModel)",
        ),
        Choice(
            "isotropic",
            "the anisotropic model's isotropic, centred special case: ΔΣ(μ0, μk) = d_k I "
            "(fitting.AnisotropicModel(isotropic=True))",
        ),
        Choice(
            "anisotropic_law",
            "the anisotropic model's base lobe (--shape) with ΔΣ(μ0, μ) from a continuous scale law: principal "
            "axes at a free angle, each variance a width law (floor + power law) in μ or, --law spline, a monotone "
            "spline in ln μ, so it predicts unseen scales (fitting.AnisotropicLawModel)",
        ),
        Choice("parametric", "a lobe family and a scale law of its slope statistics (fitting.ParametricModel)"),
        Choice("nonparametric", "a tabulated base lobe and relative statistics (fitting.NonParametricModel)"),
        Choice(
            "nonparametric_anisotropic",
            "a tabulated base lobe of any shape and centre, and relative statistics R_k(W) over the W plane: "
            "radial knots × angular harmonics, even for its modulus and odd for its phase (a change of skewness) "
            "(fitting.AnisotropicNonParametricModel)",
        ),
    ),
    default="anisotropic",
)

SHAPES = Choices(
    "shape",
    (
        Choice("gaussian", "Gaussian (Beckmann) base lobe"),
        Choice("ggx", "GGX base lobe (bivariate Student-t of tail index 2)"),
        Choice("student_t", "bivariate Student-t base lobe with a free tail index ν (heavy tails)"),
    ),
    default="gaussian",
)

INCREMENTS = Choices(
    "increments",
    (
        Choice("gaussian", "each scale's change a Gaussian of covariance ΔΣ_k (Gaussian statistics: covariances add)"),
        Choice(
            "mixture",
            "each scale's change a two-Gaussian scale mixture of the same covariance ΔΣ_k, its tail weight and "
            "width ratio shared by the scales (heavy-tailed changes: a few steep facets)",
        ),
    ),
    default="gaussian",
)

FAMILIES = Choices(
    "family",
    (
        Choice("beckmann", "Beckmann (Gaussian slopes)"),
        Choice("ggx", "GGX (Trowbridge–Reitz)"),
    ),
    default="beckmann",
)

LAWS = Choices(
    "law",
    (
        Choice("width", "WidthLaw alpha(mu) = alpha_max (1 + (mu/mu_c)^2)^(-exponent/2)"),
        Choice(
            "gaussian_surface",
            "GaussianSurface(GaussianCorrelation(rms_height, correlation_length), box window); Beckmann only",
        ),
        Choice(
            "spline",
            "monotone splines in ln mu of the principal slope variances (stats.MonotoneSplineLaw, 3 knots over the "
            "fitted scales; beyond them the power law of the end rate); anisotropic_law only",
        ),
    ),
    default="width",
)


MASKING = Choices(
    "masking",
    (
        Choice("none", "no masking or shadowing, G = 1: the seed's assumption (brdfscale.lobes.NoMasking)"),
        Choice(
            "smith",
            "Smith's height-correlated masking-shadowing G2 = 1/(1 + Λ(i) + Λ(o)) of the lobe's own slope density "
            "(brdfscale.lobes.SmithMasking)",
        ),
        Choice(
            "smith_ms",
            "smith with the light it loses to interreflection added back in the single-scattered lobe's shape, "
            "G2/E(i) (Turquin 2019; brdfscale.lobes.SmithMasking(multiple_scattering=True))",
        ),
    ),
    default="none",
)
"""Masking and shadowing in a lobe's ρ, the measurement-set forward model and the fits (docs/masking.md);
the default stays the seed's (none), as the instrument study (issue 32 item 5) decided (docs/masking.md)."""


INSTRUMENTS = Choices(
    "instrument",
    (
        Choice(
            "facets",
            "lobes from facet statistics under the seed's nearly-flat assumptions (brdfscale.synth.gonioreflectometer)",
        ),
        Choice(
            "raytraced",
            "the virtual gonioreflectometer of brdfscale.instrument, which ray-traces the height field in Mitsuba 3 "
            "(masking, shadowing, interreflection; σ = the Monte Carlo error; needs brdfscale[render])",
        ),
    ),
    default="facets",
)
"""The instrument ``brdfscale synth`` images a surface with (``--instrument``; docs/instrument.md)."""

WEIGHTINGS = Choices(
    "weighting",
    (
        Choice(
            "nearly_flat",
            "every pixel facet reflects the same light, the seed's approximation (the lobe does not depend on i)",
        ),
        Choice("projected_area", "each facet weighted by the light it intercepts, its area projected towards i"),
    ),
    default="nearly_flat",
)
"""The pixel-facet weighting of the facet-statistics instrument (``brdfscale.synth.gonioreflectometer(weighting=)``,
``brdfscale synth --weighting``)."""

MICRO_FACETS = Choices(
    "micro",
    (
        Choice("beckmann", "Beckmann facets (brdfscale.stats.Beckmann of roughness --micro-alpha)"),
        Choice("ggx", "GGX facets (brdfscale.stats.GGX of roughness --micro-alpha)"),
    ),
    default="beckmann",
)
"""The rough pixel facets' microfacet distribution of ``brdfscale synth --micro`` (in Python: the density object,
``HeightField(micro=)``)."""

BINNINGS = Choices(
    "binning",
    (
        Choice(
            "nearest",
            "each detected path in the node whose h × h cell holds its half-slope offset (independent node errors)",
        ),
        Choice(
            "bilinear",
            "shared among the four nodes around it (cloud in cell, as brdfscale.synth.gonioreflectometer bins "
            "facets; neighbouring node errors correlated)",
        ),
    ),
    default="nearest",
)
"""How the ray-traced instrument's detector bins a detected path (``brdfscale.instrument.measure(binning=)``;
docs/instrument.md, "The detector"; tests/test_instrument.py measures both binnings' node correlations)."""

MESHES = Choices(
    "surface",
    (
        Choice(
            "pixel_facets",
            "the HeightField's pixel facets, the library's own surface model (as brdfscale.synth takes statistics "
            "of), each facet over its whole pixel, joined by vertical slivers",
        ),
        Choice("triangles", "the continuous piecewise-linear surface through the heights (triangles A and B)"),
    ),
    default="pixel_facets",
)
"""The mesh the ray-traced instrument makes of a height field (``brdfscale.instrument.measure(surface=)``,
``instrument.mesh``; docs/instrument.md, "The surface")."""

EXECUTORS = Choices(
    "executor",
    (
        Choice("auto", "Ray when address or workers is given, else this process"),
        Choice("process", "one task after another in this process"),
        Choice("ray", "as Ray tasks (the extra brdfscale[cluster])"),
    ),
    default="auto",
)
"""Where tasks run: a library's batches (``brdfscale.library.fit_library(executor=)``) and a ray-traced
measurement's (``brdfscale.instrument.measure(executor=)``); :mod:`brdfscale._cluster` resolves ``"auto"``."""

FORMS = Choices(
    "form",
    (
        Choice("auto", "closed where every evolved lobe is Gaussian, else table"),
        Choice(
            "table",
            "lobe tables on a log-μ ladder, interpolated by Mitsuba (bilinear in the slope offset, linear in ln μ)",
        ),
        Choice(
            "closed",
            "the Gaussian lobe in closed form, its covariance interpolated linearly in ln μ (Gaussian evolved lobes "
            "only), Smith masking exact",
        ),
        Choice(
            "spline",
            "lobe tables on a ladder evenly spaced in ln μ, interpolated by tricubic B-splines through the values "
            "(slope offset and ln μ; the G₁ tables likewise)",
        ),
    ),
    default="auto",
)
"""The form ``brdfscale.render.bsdf(form=)`` renders a material in (docs/render.md)."""

OUTPUTS = Choices(
    "output",
    (
        Choice("radiance", "the rendered radiance"),
        Choice("footprint", "each pixel's first-hit footprint length (scene units) instead of radiance"),
    ),
    default="radiance",
)
"""What ``brdfscale.render.FootprintIntegrator(output=)`` writes (docs/render.md)."""

FOOTPRINTS = Choices(
    "footprint",
    (
        Choice("pixel", "the pixel's own footprint"),
        Choice("sample", "Mitsuba's per-sample ray differentials (1/√spp of the pixel's)"),
    ),
    default="pixel",
)
"""The observation scale ``brdfscale.render.FootprintIntegrator(footprint=)`` gives a first hit (docs/render.md)."""


@dataclasses.dataclass(frozen=True)
class FitDefaults:
    """The defaults of ``fitting.fit`` and ``fitting.fit_many`` (their docstrings say what each option does)."""

    solver: str = SOLVERS.default
    starts: int | str = "auto"
    model_starts: int = 8
    spread: float = 0.5
    seed: int = 0
    max_steps: int = 256
    rtol: float = 1e-6
    atol: float = 1e-6
    undetermined_std: float = 1.0


@dataclasses.dataclass(frozen=True)
class SampleDefaults:
    """The defaults of ``fitting.sample`` and ``fitting.sample_many`` (their docstrings say what each option does)."""

    sampler: str = SAMPLERS.default
    chains: int = 4
    steps: int | None = None
    chunk: int = 200
    seed: int = 0
    # steps None: the sampler's own (its ``default_steps``, fitting._sampler). Emcee's ensembles need
    # long chains (τ of tens of steps); NUTS/HMC, Laplace-preconditioned, draw nearly independent
    # samples each step, so far fewer pass the convergence check (ESS_bulk ≥ 400, R̂ ≤ 1.01; docs/fitting.md,
    # "Speed of the default fit", measures the margin). The warm-up tunes only the step size (the Laplace
    # covariance is the mass matrix): on bench_anisotropic's 27-parameter posterior it had settled after
    # 100 steps (averaged ε 0.62 against 0.64–0.66 after 250, R̂ ≤ 1.003, every chain converged)
    emcee_steps: int = 2000
    gradient_steps: int = 1000
    gradient_warmup: int = 100
    # independence Metropolis–Hastings: one log-density per step, so its steps are cheap; its draws are correlated
    # over a few steps (a rejected proposal repeats the state), and 1000 left R̂ too close to the 1.01 limit on the
    # benchmark's set; 3000 give R̂ 1.003 there (docs/fitting.md, "Speed of the default fit", bench_anisotropic)
    imh_steps: int = 3000
    # fitting.Auto: k̂ from 2000 proposal draws (one log-density each; the PSIS paper's threshold for that many is
    # 1 − 1/log10(2000) = 0.697) at most 0.7 runs IMH (docs/fitting.md, "Samplers" and "Speed of the default fit")
    auto_draws: int = 2000
    auto_max_k: float = 0.7
    # fitting.sample_many runs one program over many materials: a gradient sampler, not auto's per-posterior choice
    batched_sampler: str = "nuts"

    def steps_for(self, sampler: str) -> int:
        """The steps a sampler runs when none are given (``steps=None``): ``emcee_steps`` for
        emcee, ``imh_steps`` for independence Metropolis–Hastings, ``gradient_steps`` draws for NUTS and HMC
        (their ``default_steps``)."""
        return {"emcee": self.emcee_steps, "imh": self.imh_steps, "auto": self.auto_steps}.get(
            sampler, self.gradient_steps
        )

    @property
    def auto_steps(self) -> int:
        """The most steps auto's choice runs by default (its IMH's or NUTS's warm-up and draws): the bound of a
        chain's memory before the choice is made; the run itself takes the chosen sampler's own."""
        return max(self.imh_steps, self.gradient_warmup + self.gradient_steps)

    def steps_text(self) -> str:
        """What ``steps=None`` means, in words (the command's help)."""
        return (
            f"the sampler's own: nuts and hmc {self.gradient_steps} draws after {self.gradient_warmup} "
            f"warm-up steps, imh {self.imh_steps} steps, emcee {self.emcee_steps} steps; auto those of its choice"
        )


@dataclasses.dataclass(frozen=True)
class ModelDefaults:
    """The defaults of the fitting models' options: ``fitting.AnisotropicModel(shape=, increments=)``,
    ``fitting.ParametricModel(family, family, law=)`` and
    ``fitting.NonParametricModel(base_nodes=, n_knots=, regularisation=)`` (``regularisation``
    None: the weight ``smoothness`` of the smoothness prior)."""

    model: str = MODELS.default
    shape: str = SHAPES.default
    increments: str = INCREMENTS.default
    family: str = FAMILIES.default
    law: str = LAWS.default
    base_nodes: int = 13
    knots: int = 8
    regularisation: float | str | None = None
    smoothness: float = 3.0


@dataclasses.dataclass(frozen=True)
class AdequacyDefaults:
    """The thresholds of ``fitting.assess`` — whether a fit's outcome can be trusted (docs/fitting.md,
    "The outcome and the exit status"; tested in tests/test_adequacy.py).

    * ``max_reduced_chi2``, ``p_value``: a scale whose χ²/dof exceeds ``max_reduced_chi2`` with a χ²
      tail probability below ``p_value`` makes the model inadequate;
    * ``max_lag1``: a lag-1 autocorrelation of the whitened residuals along an image's rows or
      columns above ``max_lag1``, one-sided p below ``p_value`` after a Bonferroni correction over the
      fit's tests, is residual structure: the model inadequate;
    * ``min_lobe_pixels``: a lobe whose rms width along its narrower principal axis (as measured: 0.92
      of a Gaussian's) is below this many image pixel pitches is unresolved — its change with scale cannot
      be measured (a Gaussian of rms width one pitch keeps 0.7 % of its spectrum's peak at the Nyquist
      frequency: sampled without loss; narrower ones alias, and within a pixel nothing is measured);
    * ``significance``, ``peak_fraction``: the pixels whose second moments measure a lobe's width —
      above ``significance`` σ and above ``peak_fraction`` of the image's peak (noise far from the lobe
      would otherwise dominate the moments);
    * ``away_fraction``, ``away_verdict_share``: where the misfit lies — the pixels where the model predicts less
      than ``away_fraction`` of its image's peak are *away from the lobe* (``fitting.assess``'s ``away_share``: a
      diagnosis, no test); the verdict says so where the failing scale's share is above ``away_verdict_share``.
    """

    max_reduced_chi2: float = 1.5
    max_lag1: float = 0.1
    p_value: float = 1e-3
    min_lobe_pixels: float = 1.0
    significance: float = 3.0
    peak_fraction: float = 0.05
    away_fraction: float = 0.01
    away_verdict_share: float = 0.5


#: The fewest distinct scales μ a fit accepts (``fitting.Dataset``): the evolution between scales carries the
#: information; ``brdfscale synth``'s automatic scales refuse a field that admits fewer.
MIN_FIT_SCALES = 2

#: The defaults.
FIT, SAMPLE, MODEL = FitDefaults(), SampleDefaults(), ModelDefaults()
ADEQUACY = AdequacyDefaults()
