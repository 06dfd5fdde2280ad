"""Fits of measured and measured-like surfaces (issue 31, "Tests"): what the rest of the suite did not cover.

Already covered elsewhere (not repeated here):

* ΔΣ recovered within 3 standard errors on Gaussian-model data of known ΔΣ, and calibrated over
  seeds — tests/test_anisotropic.py; on the heavy-tailed *model* mixture the non-parametric
  anisotropic model fits where the Gaussian one does not — tests/test_nonparametric_aniso.py;
  ΔΣ of mi-1 and plu-1 against their facet statistics (strict xfail) — tests/test_joint.py;
  tr ΔΣ of di-3 by the isotropic width law — tests/test_topography.py;
* one slope spike and the library's default extent (synth.robust_extent) — tests/test_adequacy.py;
* a wrong model (GGX lobes, Beckmann fit) flagged inadequate, exit 5 — tests/test_adequacy.py,
  tests/test_fit_cli.py;
* nearly-square pixels made square and recorded, the MountainsMap file read, rectangular pixels'
  equal-size windows and an analytic anisotropic surface measured on them —
  tests/test_topography_robustness.py.

Added here: synthetic anisotropic and heavy-tailed *height fields* (their Σ(μ) known from their own
facet statistics) through synth.gonioreflectometer and the anisotropic fit; the real files other
than mi-1 and plu-1 through ``brdfscale synth --topography`` as a user runs it; the MetroPro-like
spike through the command (a file SurfaceTopography reads); a deliberately wrong model on a real
file and its exit status.

ΔΣ z-scores are tests/test_joint.py's: ``(fit − field)/√(std_fit² + e0² + ek²)`` per component,
e the field's stated standard errors (synth.facet_statistics). Every ΔΣ test first checks that the
field's ΔΣ stands clear of its own error (> 3 e on the diagonal), so that |z| < 3 can fail.
"""

import json
import math
from pathlib import Path

import jax
import numpy as np
import pytest

from brdfscale import _cli as cli, exr, synth


jax.config.update("jax_enable_x64", True)

from brdfscale import fitting  # noqa: E402


DATA = Path(__file__).resolve().parent / "data" / "topographies"


def _main(argv, capsys) -> tuple[int, str, str]:
    try:
        code = cli.main(["--no-compilation-cache", *argv])
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


def _z(result, statistics) -> np.ndarray:
    """(K − 1, 2, 2) z-scores of the fit's ΔΣ against the field's facet statistics (module docstring)."""
    rows = []
    for d, s in zip(result.covariance_differences, statistics[1:]):
        field = statistics[0].covariance - s.covariance
        err = np.hypot(statistics[0].covariance_error, s.covariance_error)
        rows.append((np.array(d["value"], float) - field) / np.hypot(np.array(d["std"], float), err))
    return np.array(rows)


def _has_power(statistics) -> None:
    """The field's ΔΣ at the coarsest scale exceeds 3 of its standard errors on the diagonal."""
    field = statistics[0].covariance - statistics[-1].covariance
    err = np.hypot(statistics[0].covariance_error, statistics[-1].covariance_error)
    assert np.all(np.diag(field) > 3 * np.diag(err)), (np.diag(field), np.diag(err))


def _field_fit(field, mus):
    """Facet statistics of ``field`` at ``mus`` and the anisotropic fit of its synthesised lobes (image
    extent 4 √(largest ΔΣ diagonal), 33 px, 2 px resolution, Poisson 200 counts + 1 read noise)."""
    statistics = synth.facet_statistics(field, mus, bins=17)
    spread = max(float(np.max(np.diag(statistics[0].covariance - s.covariance))) for s in statistics)
    extent = 4 * math.sqrt(spread)
    mset = synth.gonioreflectometer(
        field,
        mus,
        [0.0, 0.0, 1.0],
        extent=extent,
        pixels=33,
        resolution=2 * 2 * extent / 32,
        noise=synth.PoissonNoise(200, 1),
        seed=1,
    )
    data = fitting.Dataset.from_measurements(mset)
    assert fitting.resolution(data).ok
    return statistics, fitting.fit(fitting.AnisotropicModel(len(mus)), data, starts=2, solver="lm_normal")


@pytest.mark.slow  # ≈ 25 s on 2 loaded cores: one anisotropic fit of 3 × 33² px
def test_delta_sigma_of_an_anisotropic_field_within_three_standard_errors():
    """A Gaussian-correlated field (512² px) with correlation lengths 6 and 24 px (Σ_xx/Σ_yy ≈ 18 at 2 px): every
    ΔΣ component of the fit within 3 standard errors of the field's facet statistics, and the
    anisotropy recovered (ΔΣ_xx/ΔΣ_yy > 5 at the coarsest scale, as the field's)."""
    field = synth.named_surface("anisotropic", size=512, seed=0)
    statistics, result = _field_fit(field, [2, 4, 8])
    _has_power(statistics)
    z = _z(result, statistics)
    assert np.all(np.abs(z) < 3), z
    last = np.array(result.covariance_differences[-1]["value"])
    field_last = statistics[0].covariance - statistics[-1].covariance
    assert field_last[0, 0] > 5 * field_last[1, 1] and last[0, 0] > 5 * last[1, 1], (last, field_last)


@pytest.mark.slow  # ≈ 25 s on 2 loaded cores
@pytest.mark.xfail(
    strict=True,
    raises=AssertionError,
    reason="issue 31: no fitting model yet has heavy tails (a Gaussian lobe's least-squares ΔΣ is its core's, "
    "about a tenth of the field's second-moment ΔΣ here)",
)
def test_delta_sigma_of_a_heavy_tailed_field_within_three_standard_errors():
    """The scratched field (Gaussian texture plus V-scratches: heavy-tailed slopes) at 512² px: the
    anisotropic Gaussian model's ΔΣ against the field's — the target of the issue, not met today (the
    field's ΔΣ stands clear of its errors: that check runs first, and passes, so the failure is the z-scores')."""
    field = synth.named_surface("scratched", size=512, seed=0)
    statistics, result = _field_fit(field, [2, 4, 8])
    _has_power(statistics)
    assert np.all(np.abs(_z(result, statistics)) < 3), _z(result, statistics)


def _synth_file(tmp_path, capsys, source: str, *extra: str) -> Path:
    out = tmp_path / "m.exr"
    code, _, err = _main(["synth", "--topography", source, "--out", str(out), *extra], capsys)
    assert code == 0, err
    return out


@pytest.mark.slow  # 20–40 s per file on 2 loaded cores: the command's 8 scales of 65² px, one anisotropic fit
@pytest.mark.parametrize(
    "name",
    [
        pytest.param(
            name,
            marks=pytest.mark.xfail(
                strict=True,
                raises=AssertionError,
                reason="issue 31: real lobes are far from Gaussian (bench_real_fits: |z| up to 5–7)",
            ),
        )
        for name in ("di-3.di", "opd-1.opd", "mnt-1.mnt")
    ],
)
def test_real_file_delta_sigma_through_the_command(tmp_path, capsys, name):
    """``brdfscale synth --topography FILE`` with every default, fitted by the anisotropic model: ΔΣ within
    3 standard errors of the file's facet statistics at the scales the command chose (mi-1 and plu-1:
    tests/test_joint.py; frt-1 is left out: its facet statistics' errors exceed its ΔΣ, so |z| < 3
    could not fail)."""
    from brdfscale import topography

    path = _synth_file(tmp_path, capsys, str(DATA / name))
    mset = exr.read_measurements(path)
    mus = sorted(set(float(m) for m in mset.scales))
    statistics = synth.facet_statistics(topography.read(DATA / name), mus, bins=17)
    _has_power(statistics)
    data = fitting.Dataset.from_measurements(mset)
    assert fitting.resolution(data).ok
    result = fitting.fit(fitting.AnisotropicModel(len(mus)), data, starts=2, solver="lm_normal")
    assert np.all(np.abs(_z(result, statistics)) < 3), _z(result, statistics)


def _spiked_heights(pitch: float) -> np.ndarray:
    """A Gaussian random surface (rms slope 0.01 along x) with one pixel raised by 2 pitches: a slope
    spike of about 2, 200 times the rms slope — the MetroPro file of issue 31 (0.84 against 0.0037)."""
    heights = np.array(synth.named_surface("gaussian", size=128, seed=0).heights, dtype=float)
    heights *= 0.01 / np.std(np.diff(heights, axis=1))
    heights[64, 64] += 2.0
    return heights * pitch


def test_one_slope_spike_in_a_file_keeps_the_commands_lobes_resolved(tmp_path, capsys):
    """The MetroPro-like case through the command: ``synth --topography`` on a text height map with one
    spike chooses an extent far below the steepest slope (1.05 × steepest would put every lobe in
    one pixel) and writes lobes every scale of which the resolution check accepts."""
    from tests.references import topography_mutation as mutation

    pytest.importorskip("SurfaceTopography")
    pitch = 1e-7
    source = tmp_path / "spike.txt"
    mutation.write_ascii(str(source), _spiked_heights(pitch), pitch, pitch)
    mset = exr.read_measurements(_synth_file(tmp_path, capsys, str(source), "--scales", "auto:4"))
    extent = mset.images[0].extent
    assert extent < 0.1  # ten times the rms slope at most; the spike's slope is about 2
    data = fitting.Dataset.from_measurements(mset)
    assert fitting.resolution(data).ok
    assert min(fitting.lobe_widths(data)) >= 1.0


@pytest.mark.slow  # ≈ 40 s on 2 loaded cores: synth and a fit (its sampler not run: inadequate before sampling)
def test_an_isotropic_model_on_the_striated_file_exits_5_naming_why(tmp_path, capsys):
    """A deliberately wrong model: the isotropic parametric model on the striated confocal file plu-1
    (Σ_yy/Σ_xx of 3–35). The command writes its complete report, prints the verdict in one line on
    stderr naming the scale and the failed figure, and ends with exit status 5 (model inadequate)."""
    pytest.importorskip("SurfaceTopography")
    path = _synth_file(tmp_path, capsys, str(DATA / "plu-1.plu"))
    out = tmp_path / "fit"
    argv = ["fit", str(path), "--out", str(out), "--model", "parametric", "--no-progress"]
    code, _, err = _main([*argv, "--sampler", "emcee", "--steps", "200"], capsys)
    assert code == 5, err
    status = json.loads((out / "fit.json").read_text())["mcmc"]["status"]
    assert status.startswith("not sampled: the model is inadequate"), status  # no sampler run: inadequate already
    last = err.strip().splitlines()[-1]
    assert last.startswith("brdfscale fit: inadequate: model inadequate at μ = ") and " m: " in last, last
    doc = json.loads((out / "fit.json").read_text())
    assert doc["outcome"]["status"] == "inadequate" and doc["outcome"]["reason"] in last


@pytest.mark.slow  # ≈ 50 s on 2 cores: synth and two default fits of 8 × 65² px, one of them sampled
def test_at_low_counts_a_real_file_is_sampled_in_seconds_and_its_recorded_truth_tested(tmp_path, capsys):
    """opd-1.opd synthesised at ``poisson:0.05:1`` (README's chain, the default model). With the file as an
    instrument hands it over (the synthesised surface's record removed), the fit reaches its optimum from every
    start, leaves nothing undetermined and the default sampler (auto: the independence sampler, k̂ < 0.7)
    converges: exit 0. (Before the model's coordinates were each scale's lobe covariance, the changes between
    neighbouring scales lay below the noise on flat logarithms: undetermined directions, NUTS chosen, divergences,
    300 s and exit 6.) With the record kept, the fit's ΔΣ is tested against the surface's own and misses it by
    more than its standard errors allow — the lobes' tails lie below the noise — so the command says so: exit 5
    with that line, and no chain run for a verdict it cannot change."""
    from brdfscale import MeasurementSet

    synthesised = tmp_path / "m.exr"
    code, _, err = _main(
        ["synth", "--topography", str(DATA / "opd-1.opd"), "--noise", "poisson:0.05:1", "--out", str(synthesised)],
        capsys,
    )
    assert code == 0, err
    mset = exr.read_measurements(str(synthesised))
    assert "truth" in mset.metadata
    plain = tmp_path / "plain.exr"
    exr.write_measurements(
        str(plain), MeasurementSet(mset.images, {k: v for k, v in mset.metadata.items() if k != "truth"})
    )
    code, out, err = _main(["fit", str(plain), "--out", str(tmp_path / "F"), "--no-progress"], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "F" / "fit.json").read_text())
    assert doc["identifiability"]["undetermined_combinations"] == []
    assert all(start["at_best"] for start in doc["optimisation"]["starts"])
    assert doc["mcmc"]["sampler"] == "imh" and doc["mcmc"]["status"] == "converged", doc["mcmc"]["status"]
    assert doc["mcmc"]["chosen_by"]["pareto_k"] < doc["mcmc"]["chosen_by"]["limit"]

    code, out, err = _main(["fit", str(synthesised), "--out", str(tmp_path / "G"), "--no-progress"], capsys)
    assert code == 5, err
    last = err.strip().splitlines()[-1]
    assert "standard errors off the truth the file records" in last, last
    doc = json.loads((tmp_path / "G" / "fit.json").read_text())
    assert doc["mcmc"]["status"].startswith("not sampled: the model is inadequate"), doc["mcmc"]["status"]
    pulls = [abs(p) for d in doc["covariance_differences"] for row in d["pull"] for p in row if p is not None]
    assert max(pulls) > 5, pulls
