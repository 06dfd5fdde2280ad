"""Fuzz family "numbers": σ scaled over 60 decades, and hostile σ values (issue 34, build item 5).

Two kinds of trial, each a fit (``fitting.fit``, 2 starts) of a measurement set whose σ was
changed:

* ``sigma_scale`` — every σ multiplied by one factor c = 1e-30, 1e-20, …, 1e30 (60 decades in
  steps of 1e10; c = 1 is the reference). Scaling σ scales χ² by 1/c² and cannot move the
  optimum, so a trial is ``same`` when θ̂ equals the reference's to 1e-8 (θ are logarithms of
  the parameters for the physical models: 1e-8 relative in each), χ²·c² equals the reference
  χ² to 1e-8 relative and the status is the reference's; anything else is ``bad`` (a moved
  optimum, or a status that says "converged" where the reference did not, or the reverse). The
  full run fits the parametric model to three simulated materials (tests/helpers.TRUTHS) and the
  non-parametric model to one, its smoothness weight divided by c with σ × c (the prior's weight
  relative to the data is then the reference's: the posterior is the reference's, tempered);
  the quick run the linear model of tests/helpers at c = 1e-30, 1e-10, 1e10, 1e30.
* ``hostile_sigma`` — σ replaced, on one image (chosen by the seed) at one pixel or on all of
  them, by 0, a negative number, denormals, 1e-120 or 1e300 (outside
  ``fitting._data.SIGMA_RANGE``), inf, NaN, or by values that are valid but extreme (1e-30 and
  1e30 on one image, 1e-100 — the range's edge — on one image, 1e-30 at one pixel); and
  ``default_sigma`` = 0, −1, 1e-310, inf, NaN, 1e-30 for a set without σ. A trial is

  - ``refused``: the library's own :class:`~brdfscale.InvalidInputError` whose message names σ
    (``sigma``/``σ``) and not a shape, or a fit whose status is not ``"converged"`` (it claims
    no optimum);
  - ``same``: a fit reported ``"converged"`` with finite θ̂, χ² and estimates, at an optimum:
    SciPy's ``least_squares`` (trust-region reflective, finite differences: nobody here wrote
    it) started at θ̂ lowers χ² by less than 1e-8 of itself, or ends within the fit's own
    tolerance of θ̂ (``atol + rtol·|θ̂_i|`` in each coordinate, the defaults 1e-6: with one
    pixel 1e30 × more precise than the rest, θ̂ within 1e-10 of SciPy's optimum still leaves
    that pixel's residual, and χ², many orders above SciPy's);
  - ``bad``: anything else (a foreign exception, a message about something else, "converged"
    with a non-finite value or away from an optimum).

``quick`` uses the linear model of tests/helpers (a fit compiles in about a second) and one
trial per hostile value; the full run the parametric model on two materials, each hostile value
on two images chosen by the seed.

    python -m experiments._fuzz_numbers [--quick] [--seed N] [--json out.json]
"""

import math
import sys

import numpy as np

from experiments import _fuzz_common


KINDS = ("sigma_scale", "hostile_sigma")
FACTORS = tuple(10.0**k for k in range(-30, 31, 10) if k != 0)
"""σ × c for these c (c = 1 is the reference): 60 decades in steps of 1e10."""
QUICK_FACTORS = (1e-30, 1e-10, 1e10, 1e30)
SAME_TOLERANCE = 1e-8
"""θ̂ (logarithms) absolutely and χ²·c² relatively: the issue's "identical to 1e-8 relative"."""
OPTIMUM_TOLERANCE = 1e-8
"""SciPy started at a "converged" θ̂ may lower χ² by at most this fraction of it."""

#: (name, where, value): ``where`` is "pixel" (one pixel of one image), "image" (all of one
#: image's σ) or "default" (the set carries no σ; ``default_sigma=value``).
HOSTILE = (
    ("zero at one pixel", "pixel", 0.0),
    ("negative at one pixel", "pixel", -0.5),
    ("denormal 1e-310 at one pixel", "pixel", 1e-310),
    ("smallest denormal on one image", "image", 5e-324),
    ("1e-120 on one image", "image", 1e-120),
    ("1e300 at one pixel", "pixel", 1e300),
    ("inf at one pixel", "pixel", math.inf),
    ("nan at one pixel", "pixel", math.nan),
    ("1e-30 on one image", "image", 1e-30),
    ("1e30 on one image", "image", 1e30),
    ("1e-100 (the range's edge) on one image", "image", 1e-100),
    ("1e-30 at one pixel", "pixel", 1e-30),
    ("default_sigma 0", "default", 0.0),
    ("default_sigma -1", "default", -1.0),
    ("default_sigma 1e-310", "default", 1e-310),
    ("default_sigma inf", "default", math.inf),
    ("default_sigma nan", "default", math.nan),
    ("default_sigma 1e-30", "default", 1e-30),
)


def _setup():
    import jax

    jax.config.update("jax_enable_x64", True)


def _scaled(mset, factor: float, image: int | None = None, pixel=None, value: float | None = None):
    """``mset`` with σ × ``factor`` everywhere, or with σ of ``image`` (at ``pixel``, else all of it)
    set to ``value``; images keep their values, masks and geometry."""
    from brdfscale import LobeImage, MeasurementSet

    images = []
    for i, img in enumerate(mset.images):
        sigma = img.sigma * factor
        if i == image:
            sigma = np.array(sigma)
            if pixel is None:
                sigma[...] = value
            else:
                sigma[pixel] = value
        images.append(_image(LobeImage, img, sigma))
    return MeasurementSet(tuple(images), mset.metadata)


def _image(cls, img, sigma):
    return cls(mu=img.mu, incident=img.incident, extent=img.extent, values=img.values, sigma=sigma, mask=img.mask)


def _without_sigma(mset):
    from brdfscale import LobeImage, MeasurementSet

    return MeasurementSet(tuple(_image(LobeImage, img, None) for img in mset.images), mset.metadata)


def _materials(quick: bool):
    """(label, measurement set, model-of-dataset, smoothness-scaled?) of the trials."""
    from brdfscale import fitting
    from tests.helpers import Linear, linear_measurements, parametric_dataset, TRUTHS

    if quick:
        return [("linear", linear_measurements(seed=1), lambda data, c: Linear())]
    out = []
    parametric = fitting.ParametricModel()
    for k in (0, 1, 2):
        mset, _ = parametric_dataset(parametric, TRUTHS[k], 0.02, seed=10 + k, size=12)
        out.append((f"parametric, truth {k}", mset, lambda data, c: parametric))
    mset, _ = parametric_dataset(parametric, TRUTHS[0], 0.02, seed=20, size=12, scales=(0.5, 2.0, 8.0))
    out.append(
        (
            "nonparametric",
            mset,
            lambda data, c: fitting.NonParametricModel(
                data, base_nodes=5, n_knots=3, grid_size=16, regularisation=3.0 / c
            ),
        )
    )
    return out


def _fit(model, data):
    from brdfscale import fitting

    return fitting.fit(model, data, starts=2)


def _sigma_scale(quick: bool, tally: dict, bad: list) -> None:
    from brdfscale import fitting

    t = tally["sigma_scale"]
    for label, mset, model_of in _materials(quick):
        data = fitting.Dataset.from_measurements(mset)
        reference = _fit(model_of(data, 1.0), data)
        for c in QUICK_FACTORS if quick else FACTORS:
            t["tried"] += 1
            try:
                scaled = fitting.Dataset.from_measurements(_scaled(mset, c))
                result = _fit(model_of(scaled, c), scaled)
            except Exception as err:  # noqa: BLE001 — every failure of a valid input is bad here
                t["bad"] += 1
                bad.append(f"sigma_scale {label} c={c:g}: {type(err).__name__}: {err}"[:300])
                continue
            d_theta = float(np.max(np.abs(result.theta - reference.theta)))
            d_chi2 = abs(result.chi2 * c * c / reference.chi2 - 1)
            if d_theta <= SAME_TOLERANCE and d_chi2 <= SAME_TOLERANCE and result.status == reference.status:
                t["same"] += 1
            else:
                t["bad"] += 1
                bad.append(
                    f"sigma_scale {label} c={c:g}: |Δθ| {d_theta:.3g}, χ²·c² off by {d_chi2:.3g}, status "
                    f"{result.status!r} (reference {reference.status!r})"
                )


def _residual_function():
    import equinox as eqx

    return eqx.filter_jit(lambda theta, problem: problem.residuals(theta))


def _at_optimum(problem, result, residuals) -> str | None:
    """None when SciPy's least_squares from θ̂ cannot lower χ² by more than OPTIMUM_TOLERANCE of
    it or ends within the fit's tolerance of θ̂ (module docstring), else why not."""
    import jax.numpy as jnp
    import scipy.optimize

    from brdfscale.choices import FIT

    def f(t):
        return np.asarray(residuals(jnp.asarray(t), problem))

    tight = {"xtol": 1e-15, "ftol": 1e-15, "gtol": 1e-15}
    ref = scipy.optimize.least_squares(f, result.theta, method="trf", x_scale="jac", **tight)
    chi2 = 2 * ref.cost + float(problem.points.chi2_offset)
    near = np.all(np.abs(ref.x - result.theta) <= FIT.atol + FIT.rtol * np.abs(result.theta))
    if chi2 < result.chi2 * (1 - OPTIMUM_TOLERANCE) and not near:
        far = float(np.max(np.abs(ref.x - result.theta)))
        return f"SciPy lowers χ² from {result.chi2:.6g} to {chi2:.6g}, moving θ by up to {far:.3g}"
    return None


def _hostile(quick: bool, seed: int, tally: dict, bad: list) -> None:
    from brdfscale import fitting, InvalidInputError

    t = tally["hostile_sigma"]
    rng = np.random.default_rng([seed, 34])
    residuals = _residual_function()
    materials = _materials(quick)[: 1 if quick else 2]
    for label, mset, model_of in materials:
        for name, where, value in HOSTILE:
            for _ in range(1 if quick else 2):
                image = int(rng.integers(len(mset.images)))
                n = mset.images[image].size
                pixel = (int(rng.integers(n)), int(rng.integers(n)))
                what = f"hostile_sigma {label}: {name}" + ("" if where == "default" else f" (image {image})")
                t["tried"] += 1
                try:
                    if where == "default":
                        data = fitting.Dataset.from_measurements(_without_sigma(mset), default_sigma=value)
                    else:
                        changed = _scaled(mset, 1.0, image, pixel if where == "pixel" else None, value)
                        data = fitting.Dataset.from_measurements(changed)
                    model = model_of(data, 1.0)
                    result = _fit(model, data)
                except InvalidInputError as err:
                    message = str(err)
                    if ("sigma" in message or "σ" in message) and "shape" not in message:
                        t["refused"] += 1
                    else:
                        t["bad"] += 1
                        bad.append(f"{what}: refused with a message not about σ: {message}"[:300])
                    continue
                except Exception as err:  # noqa: BLE001 — a foreign exception is the finding
                    t["bad"] += 1
                    bad.append(f"{what}: {type(err).__name__}: {err}"[:300])
                    continue
                if result.status != "converged":
                    t["refused"] += 1  # an honest status: no optimum claimed
                    continue
                values = [result.chi2, *result.theta, *result.estimates.values()]
                if not all(math.isfinite(v) for v in values):
                    t["bad"] += 1
                    bad.append(f"{what}: 'converged' with a non-finite χ², θ̂ or estimate")
                    continue
                why = _at_optimum(fitting.Problem(model, data), result, residuals)
                if why is None:
                    t["same"] += 1
                else:
                    t["bad"] += 1
                    bad.append(f"{what}: 'converged' away from an optimum: {why}")


def run(quick: bool, seed: int = 0, directory: str | None = None) -> dict:
    """The family's tallies (module docstring); ``directory`` is unused: every trial runs in
    memory, no file is written."""
    _setup()
    tally = _fuzz_common.tally(KINDS)
    bad: list[str] = []
    _sigma_scale(quick, tally, bad)
    _hostile(quick, seed, tally, bad)
    return {"kinds": tally, "bad_examples": bad[:20]}


if __name__ == "__main__":
    sys.exit(_fuzz_common.main(run, __doc__))
