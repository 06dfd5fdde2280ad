"""Fixtures shared by several test modules, and by the experiments that measure the same things.

Test modules never import each other, nor experiments/ (tests/test_layout.py checks it): what
more than one of them needs lives here, and independent reference implementations (mpmath,
SciPy quadrature) live in tests/references/. experiments/ imports these too (from the checkout:
``from tests.helpers import …``), so that a benchmark and a test measure against one copy.

* the linear-Gaussian model (:class:`Linear`, :func:`linear_measurements`): a posterior known
  exactly (tests/test_samplers.py, tests/test_sample_many.py);
* the parametric model's simulated datasets (:data:`TRUTHS`, :func:`parametric_dataset`;
  tests/test_fit.py, tests/test_fit_slow.py, tests/test_samplers.py);
* synthetic material libraries of mixed sizes (:func:`material`, :func:`write_library`;
  tests/test_library.py, tests/test_batch.py, experiments/bench_library.py);
* measurement files and command lines for the robustness tests (:func:`sample_set`,
  :func:`same_set`, :func:`rewrite_exr`, :data:`SYNTH_DOMAINS`, :func:`run_cli`,
  :func:`run_command`; tests/test_robustness.py, experiments/fuzz_robustness.py);
* a sampled fit through the command and its report (:func:`write_sampled_set`,
  :func:`comparable_report`; tests/test_checkpoint_integrity.py, tests/test_cli_rewind.py,
  experiments/_fuzz_checkpoints.py).
"""

import contextlib
import io
import json
import math
import os
import traceback
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import OpenEXR

import brdfscale as bs
from brdfscale import exr, fitting, LobeImage, MeasurementSet
from brdfscale._cli import main as cli_main
from brdfscale.exr import _format


TOPOGRAPHIES = Path(__file__).resolve().parent / "data" / "topographies"
"""The measured instrument files of tests/data (their licences in its README.md)."""


# -- the linear-Gaussian model ----------------------------------------------------------------------

BOX = 5.0
TRUE = (1.0, 0.5, -0.3)


class Linear(fitting.AbstractModel):
    """``f_k(u) = θ0 + θ1·10u_x + θ2·(10u_x + 5u_y + k)`` (+ θ3 times the last basis again when
    ``duplicate``: a null direction θ2 − θ3); prior box [−5, 5] in every coordinate."""

    duplicate: bool = eqx.field(static=True, default=False)

    @property
    def names(self):
        return ("t0", "t1", "t2") + (("t3",) if self.duplicate else ())

    @property
    def radial(self):
        return False

    def _basis(self, points):
        k = jnp.arange(points.shape[0], dtype=points.dtype)[:, None]
        ux, uy = 10 * points[..., 0], 10 * points[..., 1]
        basis = [jnp.ones_like(ux), ux, ux + 0.5 * uy + k]
        return jnp.stack(basis + basis[-1:] * self.duplicate, axis=-1)

    def predict_points(self, theta, scales, points):
        return self._basis(points) @ theta

    def quantities(self, theta):
        out = {f"q{i}": theta[i] for i in range(3)}
        if self.duplicate:
            out["q3"] = theta[3]
        return out

    def initial(self, data):
        return np.zeros(len(self.names))

    def bounds(self, data):
        n = len(self.names)
        return np.full(n, -BOX), np.full(n, BOX)

    def relative_statistics(self, theta, W, scales):
        return jnp.ones((jnp.asarray(scales).shape[0], jnp.asarray(W).shape[0]))

    @property
    def identifiability_notes(self):
        return ()


def linear_measurements(seed=0, size=6, sigma=0.1):
    """The linear model's images at μ = 1 and 2, ``size`` pixels per side (or a pair: one per scale)."""
    rng = np.random.default_rng(seed)
    sizes = (size, size) if np.ndim(size) == 0 else size
    images = []
    for k, (mu, n) in enumerate(zip((1.0, 2.0), sizes)):
        axis = np.linspace(-0.1, 0.1, n)
        ux, uy = np.meshgrid(axis, axis)
        f = TRUE[0] + TRUE[1] * 10 * ux + TRUE[2] * (10 * ux + 5 * uy + k)
        images.append(
            LobeImage(
                mu=mu,
                incident=np.array([0.0, 0.0, 1.0]),
                extent=0.1,
                values=f + sigma * rng.standard_normal(f.shape),
                sigma=np.full(f.shape, sigma),
            )
        )
    return MeasurementSet(tuple(images))


# -- the parametric model's datasets ----------------------------------------------------------------

SCALES = (0.5, 1.0, 2.0, 4.0, 8.0)
TRUTHS = [
    {"amplitude": 0.8, "alpha_lobe": 0.05, "alpha_max": 0.2, "mu_c": 1.0, "exponent": 0.8},
    {"amplitude": 2.5, "alpha_lobe": 0.08, "alpha_max": 0.15, "mu_c": 2.0, "exponent": 1.5},
    {"amplitude": 0.3, "alpha_lobe": 0.03, "alpha_max": 0.25, "mu_c": 0.7, "exponent": 0.6},
]


def parametric_dataset(model, truth, noise, seed, scales=SCALES, size=24):
    """A simulated measurement set of ``model`` at ``truth`` and its fitting.Dataset."""
    mset = fitting.simulate(model, truth, scales, size=size, extent=0.5, noise=noise, floor=1e-3, seed=seed)
    return mset, fitting.Dataset.from_measurements(mset)


# -- synthetic material libraries of mixed sizes ----------------------------------------------------
# Material ``i`` of a library is a Beckmann lobe with a Beckmann width law (the demo's parametric
# model) at truths drawn around the ranges of TRUTHS, measured at five scales with its own image
# size (16–32 px), extent (0.4–0.6) and number of replicate images (1 or 2) — a lab whose set-up
# changes from sample to sample, so that no two materials need share a compiled fit unless the
# fits are bucketed (``fitting.fit_many``).


def write_sampled_set(path) -> str:
    """A small measurement set of the parametric model (scales 1, 2, 8; 16 × 16 pixels; noise
    0.01) that ``brdfscale fit --model parametric --sampler emcee`` fits and samples in seconds:
    the command's checkpoint and report tests (tests/test_checkpoint_integrity.py,
    tests/test_cli_rewind.py) and the checkpoints fuzz family. Returns ``path``."""
    truth = dict(amplitude=0.8, alpha_lobe=0.08, alpha_max=0.2, mu_c=1.0, exponent=0.8)
    mset = fitting.simulate(
        fitting.ParametricModel(), truth, (1.0, 2.0, 8.0), size=16, extent=0.15, noise=0.01, floor=1e-3, seed=2
    )
    exr.write_measurements(path, mset)
    return os.fspath(path)


def sampled_fit_argv(measurements, out, *, steps: int, chains: int = 2) -> list[str]:
    """``brdfscale fit`` of :func:`write_sampled_set`'s file into ``out``: the parametric model,
    one start, emcee with 16 walkers × ``chains`` for ``steps`` steps (checkpointed in
    ``out/chain.h5`` every ``choices.SAMPLE.chunk`` steps), no progress bar."""
    return [
        *("fit", os.fspath(measurements), "--out", os.fspath(out), "--model", "parametric", "--starts", "1"),
        *("--sampler", "emcee", "--walkers", "16", "--chains", str(chains), "--steps", str(steps), "--no-progress"),
    ]


def comparable_report(out) -> dict:
    """``out/fit.json`` without what differs between two runs of one fit into two directories: the
    paths into their own directory (figures, posterior, tables) and the sampler's timing."""
    with open(os.path.join(out, "fit.json"), encoding="utf-8") as f:
        doc = json.load(f)
    for key in ("figures", "posterior", "tables"):
        doc.pop(key, None)
    (doc.get("mcmc") or {}).pop("timing_s", None)
    return doc


LIBRARY_SIZES = (16, 20, 24, 28, 32)
LIBRARY_EXTENTS = (0.4, 0.5, 0.6)


def library_truth(i: int, seed: int = 0) -> dict:
    rng = np.random.default_rng([seed, i])
    return {
        "amplitude": float(rng.uniform(0.3, 2.5)),
        "alpha_lobe": float(rng.uniform(0.04, 0.08)),
        "alpha_max": float(rng.uniform(0.15, 0.25)),
        "mu_c": float(rng.uniform(0.7, 2.0)),
        "exponent": float(rng.uniform(0.6, 1.5)),
    }


def material(i: int, seed: int = 0, noise: float = 0.02):
    """The measurement set of material ``i`` (needs float64 JAX)."""
    from brdfscale import fitting

    rng = np.random.default_rng([seed, i, 1])
    model = fitting.ParametricModel()
    return fitting.simulate(
        model,
        library_truth(i, seed),
        SCALES,
        size=int(rng.choice(LIBRARY_SIZES)),
        extent=float(rng.choice(LIBRARY_EXTENTS)),
        noise=noise,
        floor=1e-3,
        replicates=int(rng.integers(1, 3)),
        seed=int(rng.integers(2**31)),
    )


def write_library(directory: str, n: int, seed: int = 0) -> list[str]:
    """Write materials 0 … n−1 as ``directory/material_NNN.exr``; return the paths."""
    os.makedirs(directory, exist_ok=True)
    paths = []
    for i in range(n):
        path = os.path.join(directory, f"material_{i:03d}.exr")
        exr.write_measurements(path, material(i, seed), overwrite=True)
        paths.append(path)
    return paths


# -- measurement files and command lines for the robustness tests -----------------------------------


def sample_set() -> bs.MeasurementSet:
    """A small valid measurement set: two parts, RGB values, σ, mask, nested metadata with non-ASCII text."""
    rng = np.random.default_rng(7)
    images = []
    for k, mu in enumerate((2.0, 8.0)):
        v = rng.random((9, 9, 3)) + 0.1
        images.append(
            bs.LobeImage(
                mu=mu,
                incident=np.array([0.1 * k, 0.0, np.sqrt(1 - 0.01 * k * k)]),
                extent=0.2,
                values=v,
                sigma=0.05 + 0.1 * v,
                mask=v[..., 0] > 0.3,
            )
        )
    return bs.MeasurementSet(
        tuple(images), {"surface": {"name": "fuzz"}, "truth": {"params": {"mu_c": 3.0}}, "note": "ünïcode"}
    )


def same_set(a: bs.MeasurementSet, b: bs.MeasurementSet) -> bool:
    """Whether two measurement sets hold the same data bit for bit (values, σ, mask, geometry, metadata)."""
    if len(a.images) != len(b.images) or a.metadata != b.metadata:
        return False
    for p, q in zip(a.images, b.images):
        for x, y in ((p.values, q.values), (p.sigma, q.sigma), (p.mask, q.mask), (p.incident, q.incident)):
            if (x is None) != (y is None) or (x is not None and not np.array_equal(x, y)):
                return False
        if p.mu != q.mu or p.extent != q.extent:
            return False
    return True


def rewrite_exr(src: str, dst: str, edit, reseal: bool = False) -> None:
    """Copy ``src`` to ``dst`` through OpenEXR, applying ``edit(index, header, channels)``."""
    parts = []
    for index, part in enumerate(OpenEXR.File(src, separate_channels=True).parts):
        header = dict(part.header)
        channels = {name: c.pixels for name, c in part.channels.items()}
        edit(index, header, channels)
        for key in ("channels", "chunkCount", "dataWindow", "type"):
            header.pop(key, None)
        if reseal:
            header[_format.PREFIX + _format.DIGEST] = _format.header_digest(header, channels)
        parts.append(OpenEXR.Part(header, channels, name=part.header.get("name", f"p{index}")))
    OpenEXR.File(parts).write(dst)


#: values tried for command-line options: negative, zero, huge, not finite, empty, text, hexadecimal, …
HOSTILE = [
    "-1",
    "0",
    "1e300",
    "-1e300",
    "nan",
    "inf",
    "",
    "1180591620717411303424",
    "abc",
    "1e-30",
    "100000",
    "0x10",
    "1.5",
    "2",
    "3",
    "-0",
    "1e9",
    "65",
    "∞",
]


def _number(text: str, lo, hi, *, strict: bool = False, integral: bool = False) -> bool:
    try:
        x = int(text) if integral else float(text)
    except ValueError:
        return False
    return math.isfinite(x) and (x > lo if strict else x >= lo) and x <= hi


#: synth's options and their documented domains (``brdfscale synth --help``), for the
#: template ``--size 16 --scales 2,4``: a scale must not exceed the size, the size not be
#: below the largest scale.
SYNTH_DOMAINS = {
    "--pixels": lambda t: _number(t, 3, 1025, integral=True),
    "--size": lambda t: _number(t, 16, 4096, integral=True),
    "--seed": lambda t: _number(t, 0, 2**32 - 1, integral=True),
    "--extent": lambda t: _number(t, 0, 1000, strict=True),
    "--resolution": lambda t: _number(t, 0, 10),
    "--micro-alpha": lambda t: _number(t, 0, 10, strict=True),
    "--scales": lambda t: _number(t, 1, 16) and float(t) == round(float(t)),
}


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """``brdfscale ARGV`` in this process, without the persistent compilation cache: (exit
    status, stdout, stderr); a traceback of an exception that escaped ``main`` is in stderr with
    status −1."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli_main(["--no-compilation-cache", *argv])
        except SystemExit as exit_:  # argparse's usage errors
            code = exit_.code if isinstance(exit_.code, int) else 1
        except BaseException as exc:  # noqa: BLE001 — main() must never let one out
            traceback.print_exc(file=err)
            code = -1
            del exc
    return code, out.getvalue(), err.getvalue()


def run_command(argv: list[str]) -> tuple[int, str]:
    """:func:`run_cli` without its stdout: (exit status, stderr)."""
    code, _, err = run_cli(argv)
    return code, err


# --- anisotropic Gaussian lobes: a hand-written NumPy oracle (tests/test_anisotropic.py, tests/test_joint.py)

ANISO_SCALES = (1.0, 2.0, 4.0)
ANISO_SIZE, ANISO_EXTENT = 17, 0.5


def rotation(phi):
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s], [s, c]])


def gaussian(u, mean, cov, amplitude):
    """``A exp(−½ dᵀC⁻¹d)/(2π √det C)``, by hand."""
    d = u - mean
    q = np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d)
    return amplitude * np.exp(-q / 2) / (2 * np.pi * np.sqrt(np.linalg.det(cov)))


def anisotropic_grid():
    x = np.linspace(-ANISO_EXTENT, ANISO_EXTENT, ANISO_SIZE)
    return np.stack(np.meshgrid(x, x), axis=-1)  # rows u_y, columns u_x (brdfscale.LobeImage)


ANISO_TRUTH = {
    "amplitude": 2.0,
    "mean": np.array([0.03, -0.02]),
    "C0": rotation(0.4) @ np.diag([0.01, 0.002]) @ rotation(0.4).T,
    "steps": [
        rotation(0.3) @ np.diag([0.006, 0.001]) @ rotation(0.3).T,
        rotation(-0.2) @ np.diag([0.004, 0.002]) @ rotation(-0.2).T,
    ],
}


def anisotropic_differences():
    return np.cumsum([np.zeros((2, 2)), *ANISO_TRUTH["steps"]], axis=0)


def noisy_dataset(lobes, scales, extent, rng, noise=0.01, floor=1e-3):
    """A fitting.Dataset of normal-incidence images of the noiseless ``lobes`` (one square array per
    scale, rows u_y) over ``[−extent, extent]²``, each with Gaussian noise of standard deviation
    ``noise × its peak + floor`` drawn from ``rng`` image by image (σ stored)."""
    from brdfscale import fitting

    images = []
    for mu, v in zip(scales, lobes):
        sigma = noise * v.max() + floor
        images.append(
            bs.LobeImage(
                mu=mu,
                incident=[0.0, 0.0, 1.0],
                extent=extent,
                values=v + sigma * rng.standard_normal(v.shape),
                sigma=np.full(v.shape, sigma),
            )
        )
    return fitting.Dataset.from_measurements(bs.MeasurementSet(tuple(images)))


def anisotropic_dataset(seed, noise=0.01, floor=1e-3):
    """Images of the true anisotropic Gaussian lobe at the three scales with Gaussian noise."""
    u = anisotropic_grid()
    lobes = [
        gaussian(u, ANISO_TRUTH["mean"], ANISO_TRUTH["C0"] + d, ANISO_TRUTH["amplitude"])
        for d in anisotropic_differences()
    ]
    return noisy_dataset(lobes, ANISO_SCALES, ANISO_EXTENT, np.random.default_rng(seed), noise, floor)


def anisotropic_theta(model, amplitude, c0, mean, differences):
    """θ of AnisotropicModel for given physical values (inverse of its parameterisation)."""

    def chol(m):
        L = np.linalg.cholesky(m)
        return [math.log(L[0, 0]), L[1, 0], math.log(L[1, 1])]

    theta = [math.log(amplitude), *chol(c0)]
    if not model.centred:
        theta += list(mean)
    for d in np.asarray(differences)[1:]:  # the lobe's covariance C_k = C0 + ΔΣ_k at each coarser scale
        theta += chol(np.asarray(c0) + d)
    return jnp.asarray(theta)


def fit_at(names, theta, covariance, n_data: int, *, solver: str = "lm", **extra) -> fitting.FitResult:
    """A ``fitting.FitResult`` at θ with covariance ``covariance`` and nothing else (no starts, estimates, notes or
    undetermined directions; χ² 1): what a figure or an export reads of a fit, for tests that run no fit.
    ``extra``: further fields (``covariance_differences``, ``ratios``, …)."""
    return fitting.FitResult(
        names=names,
        theta=theta,
        covariance=covariance,
        chi2=1.0,
        n_data=n_data,
        status="converged",
        starts=[],
        estimates={},
        std={},
        quantiles={},
        eigenvalues=np.ones(len(names)),
        undetermined=[],
        notes=[],
        solver=solver,
        at_bounds=[],
        **extra,
    )


def image_covariance(values, extent):
    """The second central moment (2, 2) of an image's node values over its offsets u (rows u_y, columns u_x, the
    nodes of ``[−extent, extent]²``), written out with NumPy's weighted covariance (the values as weights):
    the oracle of fitting.moment_covariance_differences (tests/test_moments.py, tests/test_adequacy.py) and of the
    recorded ΔΣ truth (tests/test_covariance_truth.py)."""
    values = np.asarray(values, dtype=float)
    x = np.linspace(-extent, extent, values.shape[0])
    ux, uy = np.meshgrid(x, x)
    u = np.stack((ux.ravel(), uy.ravel()), axis=-1)
    return np.cov(u.T, aweights=values.ravel(), bias=True)
