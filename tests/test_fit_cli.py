"""The ``brdfscale fit`` command on small synthetic files: its default model (anisotropic),
``--shape``, ``--compare``, the non-parametric model, the outcome and the exit status.

These are tests of the command's path (options, model, fit, report, tables), kept fast with
coarse models (the non-parametric one: 7 × 7 base nodes, 3 knots, 40 solver steps) that need not
converge: the report must then say so. Recovery is tests/test_anisotropic.py's and
tests/test_fit_slow.py's job.
"""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from brdfscale import exr, fitting
from brdfscale._cli import main
from brdfscale.choices import SAMPLE


TRUTH = dict(amplitude=0.8, alpha_lobe=0.06, alpha_max=0.2, mu_c=1.0, exponent=0.8)
SCALES = (0.5, 2.0, 8.0)


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_nonparametric_fit_command(tmp_path, capsys):
    # 21 px over ±0.35: the finest lobe (rms width α/√2 = 0.042 per axis) spans 1.2 image pixels,
    # resolved for fitting.assess (at 12 px it spans 0.66 and the command refuses it with exit 7)
    mset = fitting.simulate(
        fitting.ParametricModel(), TRUTH, SCALES, size=21, extent=0.35, noise=0.01, floor=1e-3, seed=2
    )
    path = tmp_path / "m.exr"
    exr.write_measurements(str(path), mset)
    out = tmp_path / "out"
    argv = [
        "fit",
        str(path),
        "--model",
        "nonparametric",
        "--base-nodes",
        "7",
        "--knots",
        "3",
        "--max-steps",
        "40",
        "--starts",
        "1",
        "--steps",
        "0",
        "--out",
        str(out),
        "--no-progress",
        "--regularisation",
        "2.5",
    ]
    code = main(argv)
    printed = capsys.readouterr().out
    doc = json.loads((out / "fit.json").read_text())
    # the coarse model need not converge or fit: the exit status is the report's verdict, whichever it is
    assert code == {"ok": 0, "inadequate": 5, "not_converged": 6}[doc["outcome"]["status"]]
    assert doc["model"]["kind"] == "nonparametric" and doc["model"]["base_nodes"] == 7
    assert len(doc["model"]["knots_W"]) == 4 and doc["model"]["smoothness"] == 2.5
    status = doc["optimisation"]["status"]
    assert status in ("converged", "nonlinear_max_steps_reached") and status in printed
    assert np.isfinite(doc["optimisation"]["reduced_chi2"])
    # the reported quantities: the amplitude and D_k at the 3 knots of the 2 coarser scales
    names = [n for n in doc["parameters"] if n.startswith("D[")]
    assert len(names) == 6 and "amplitude" in doc["parameters"]
    for name in names + ["amplitude"]:
        row = doc["parameters"][name]
        assert row["source"] == "laplace"
        if row["determined"]:
            assert row["std"] > 0 and row["quantiles_5_50_95"][0] <= row["estimate_map"] <= row["quantiles_5_50_95"][2]
    # amplitude: the integral of the lobe, well determined whatever the tabulation
    amplitude = doc["parameters"]["amplitude"]
    assert amplitude["determined"] and abs(amplitude["estimate_map"] - TRUTH["amplitude"]) < 0.1 * TRUTH["amplitude"]
    assert any("NOT determined" in note for note in doc["identifiability"]["notes"])
    for fig in ("data_vs_fit.png", "statistics.png"):
        assert (out / fig).read_bytes()[:4] == b"\x89PNG"
    assert exr.read_measurements(str(out / "evolved_lobes.exr")).scales.tolist() == list(SCALES)


# -- the outcome and the exit status (issue 31: fitting.assess through the command) ---------------------------

DI = str(Path(__file__).parent / "data" / "topographies" / "di-3.di")
ADEQUATE = dict(amplitude=1.0, alpha_lobe=0.1, alpha_max=0.3, mu_c=4.0, exponent=1.0)


def _simulated_file(tmp_path, family: str, seed: int) -> str:
    mset = fitting.simulate(
        fitting.ParametricModel(family, family),
        ADEQUATE,
        (1.0, 4.0, 16.0),
        size=25,
        extent=0.5,
        noise=0.02,
        floor=1e-3,
        seed=seed,
    )
    path = tmp_path / f"{family}-{seed}.exr"
    exr.write_measurements(str(path), mset)
    return str(path)


@pytest.mark.slow  # two fits compiled afresh: 20–80 s on 2 shared cores (fitting.assess itself: tests/test_adequacy.py)
def test_a_correct_model_exits_0_with_pulls_and_a_wrong_one_exits_5(tmp_path, capsys):
    """Beckmann lobes fitted by the Beckmann model: exit 0, the truth/pull table printed as the demo
    prints it; GGX lobes fitted by the same model: exit 5 after the complete report, one line on
    stderr naming the worst scale and its figure — not sampled though sampling was asked for (inadequate before
    sampling; fit.json's mcmc says so), sampled with --sample-inadequate."""
    fit = ["--no-compilation-cache", "fit", "--model", "parametric", "--steps", "0", "--starts", "2"]
    fit += ["--no-progress", "--out"]
    assert main([*fit, str(tmp_path / "ok"), _simulated_file(tmp_path, "beckmann", 3)]) == 0
    printed = capsys.readouterr()
    assert "|est−truth|/std" in printed.out and "outcome: ok" in printed.out and printed.err == ""
    doc = json.loads((tmp_path / "ok" / "fit.json").read_text())
    assert doc["outcome"]["status"] == "ok" and len(doc["outcome"]["scales"]) == 3
    for name, value in ADEQUATE.items():  # the pulls printed are those of the report's rows
        row = doc["parameters"][name]
        assert row["truth"] == value
        estimate = row["median"] if row["median"] is not None else row["estimate_map"]
        pull = "—" if row["std"] is None else f"{abs(estimate - value) / row['std']:.2f}"  # — : undetermined
        assert printed.out.split(f"\n{name} ")[1].splitlines()[0].endswith(f"  {pull}")

    # the wrong model with sampling asked for: not sampled (inadequate before sampling), the same verdict
    steps = fit.index("--steps")
    sampled = [*fit[:steps], *fit[steps + 2 : -1], "--sampler", "imh", "--steps", "30", "--out"]
    wrong = _simulated_file(tmp_path, "ggx", 3)
    assert main([*sampled, str(tmp_path / "wrong"), wrong]) == 5
    printed = capsys.readouterr()
    (line,) = printed.err.splitlines()
    assert line.startswith("brdfscale fit: inadequate: model inadequate at μ = ") and " px: " in line
    assert "  not sampled: the model is inadequate before sampling" in printed.out
    doc = json.loads((tmp_path / "wrong" / "fit.json").read_text())
    assert doc["outcome"]["status"] == "inadequate" and doc["outcome"]["reason"] in line
    assert doc["mcmc"] == {"status": "not sampled: " + printed.out.split("  not sampled: ")[1].splitlines()[0]}
    assert (tmp_path / "wrong" / "data_vs_fit.png").exists()  # the complete report, then the status
    assert not (tmp_path / "wrong" / "chain.h5").exists()
    # --sample-inadequate: sampled all the same, still exit 5
    assert main([*sampled, str(tmp_path / "anyway"), "--sample-inadequate", wrong]) == 5
    doc = json.loads((tmp_path / "anyway" / "fit.json").read_text())
    assert doc["outcome"]["status"] == "inadequate" and doc["mcmc"]["sampler"] == "imh"
    assert (tmp_path / "anyway" / "chain.h5").exists()


def test_an_unresolved_lobe_is_refused_with_7_before_the_fit(tmp_path, capsys):
    """An extent of 50 slope units puts every lobe of di-3 (rms slope 0.19) into a pixel or two: the
    fit is refused before any work, one line saying why and what to do, exit 7, no report."""
    data = tmp_path / "wide.exr"
    argv = ["synth", "--topography", DI, "--pixels", "33", "--scales", "auto:3", "--extent", "50"]
    assert main([*argv, "--out", str(data)]) == 0
    capsys.readouterr()
    assert main(["fit", str(data), "--out", str(tmp_path / "F"), "--no-progress"]) == 7
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("brdfscale fit: undetermined: the lobe at μ = ") and " m is " in line
    assert "smaller image extent" in line and "finer angular resolution" in line
    assert not (tmp_path / "F" / "fit.json").exists()


def test_synth_topography_defaults_make_a_file_fit_can_use(tmp_path, capsys):
    """README's chain, its first half: synth --topography stores σ (poisson:200:1), an extent from
    robust slope quantiles and an instrument resolution of 2 image pixels, each recorded in the
    metadata; the lobes are resolved (the check fit runs first)."""
    from brdfscale import synth, topography

    jax_free = tmp_path / "m.exr"
    assert main(["synth", "--topography", DI, "--pixels", "33", "--scales", "auto:3", "--out", str(jax_free)]) == 0
    mset = exr.read_measurements(str(jax_free))
    assert all(image.sigma is not None for image in mset.images)
    assert mset.metadata["noise"] == {"type": "poisson", "exposure": 200.0, "read_noise": 1.0}
    field = topography.read(DI)
    assert mset.metadata["extent"] == pytest.approx(synth.robust_extent(field))
    assert mset.metadata["resolution"] == pytest.approx(2 * 2 * mset.metadata["extent"] / 32)
    assert set(mset.metadata["defaults"]) == {"extent", "noise", "resolution"}
    assert fitting.resolution(fitting.Dataset.from_measurements(mset)).status == "ok"


@pytest.mark.slow  # ≈ 40 s on 2 cores: a fit of a measured surface at README's defaults but for small images
def test_readme_measured_surface_chain_runs_as_written(tmp_path, capsys):
    """README: brdfscale topography FILE; brdfscale synth --topography FILE; brdfscale fit — on di-3 the
    default (anisotropic) model's report, its exit status the report's verdict (5 with its reason on
    stderr naming the scale in metres); every printed estimate inside its printed prior range."""
    assert main(["topography", DI, "--out", str(tmp_path / "D")]) == 0
    data = tmp_path / "m.exr"
    assert main(["synth", "--topography", DI, "--pixels", "33", "--scales", "auto:4", "--out", str(data)]) == 0
    code = main(["fit", str(data), "--out", str(tmp_path / "F"), "--no-progress", "--steps", "0"])
    printed = capsys.readouterr()
    doc = json.loads((tmp_path / "F" / "fit.json").read_text())
    assert doc["model"]["kind"] == "anisotropic" and doc["model"]["solver"] == "lm_normal"
    assert code == {"ok": 0, "inadequate": 5, "not_converged": 6}[doc["outcome"]["status"]]
    if code == 5:
        assert printed.err.strip().endswith(doc["outcome"]["reason"]) and " m: " in doc["outcome"]["reason"]
    for line in printed.out.splitlines():
        if "prior range" in line:
            lo, hi, best = (float(x) for x in re.findall(r"range (\S+) … (\S+); best fit (\S+)\)", line)[0])
            assert lo * (1 - 1e-3) <= best <= hi * (1 + 1e-3), line
    # ΔΣ against the facet statistics the file records of di-3 (fitting.covariance_truth), printed with the pulls
    truth = fitting.covariance_truth(exr.read_measurements(data).metadata, doc["data"]["scales"])
    assert truth is not None and [d["truth"] for d in doc["covariance_differences"]] == truth
    assert "ΔΣ(μ0, μk) against the surface the file was made from" in printed.out
    assert re.search(r"\d+ of \d+ entries within 3 std of the truth", printed.out)


def test_an_estimate_on_a_prior_bound_is_said_to_be_there():
    from brdfscale._cli._fit import print_determined

    row = {"median": 0.05, "estimate_map": 0.05, "determined": True, "std": 0.01, "quantiles_5_50_95": None}
    doc = {"parameters": {"exponent": row, "alpha_max": row}, "optimisation": {"at_prior_bounds": ["log exponent"]}}
    lines = []
    print_determined(doc, stream=lines.append)
    assert lines[0].startswith("  exponent") and lines[0].endswith("its estimate is at a bound of its prior range")
    assert lines[1].startswith("  alpha_max") and "bound" not in lines[1]
    # a coordinate of θ that no quantity's line names (a mixture's f, a Cholesky factor) has a line of its own
    doc["optimisation"]["at_prior_bounds"] = ["log exponent", "log f-1"]
    lines = []
    print_determined(doc, stream=lines.append)
    assert lines[2] == "  θ coordinates at a prior bound: log f-1 (fit.json's optimisation.at_prior_bounds)"


# -- the default model, --shape and --compare (issue 31 items 1 and 8) -------------------------------------


def test_the_default_model_is_the_anisotropic_one_with_normal_equation_steps():
    """No --model: fitting.AnisotropicModel with a Gaussian base lobe, solver "auto" resolved to
    lm_normal in the report's model description; --model isotropic is its isotropic special case;
    --shape reaches the model, and is refused where it does not apply."""
    from brdfscale import InvalidInputError
    from brdfscale._cli import build_parser
    from brdfscale._cli._fit import check_fit_options, spec_of

    data = fitting.Dataset.from_measurements(
        fitting.simulate(fitting.ParametricModel(), TRUTH, SCALES, size=9, extent=0.35, noise=0.01, seed=0)
    )

    def parsed(*extra):
        args = build_parser().parse_args(["fit", "m.exr", "--out", "d", *extra])
        check_fit_options(args)
        return args

    model, info = spec_of(parsed()).model_for(data)
    assert isinstance(model, fitting.AnisotropicModel) and not model.isotropic and model.shape == "gaussian"
    assert info["kind"] == "anisotropic" and info["solver"] == "lm_normal"
    model, info = spec_of(parsed("--model", "isotropic", "--shape", "student_t")).model_for(data)
    assert model.isotropic and model.shape == "student_t" and model.names[-1] == "log nu"
    assert spec_of(parsed("--model", "parametric")).model_for(data)[1]["solver"] == "lm"
    with pytest.raises(InvalidInputError, match="--shape applies to the anisotropic and isotropic models"):
        parsed("--model", "parametric", "--shape", "ggx")
    with pytest.raises(InvalidInputError, match=r"--fix applies to the parametric model only \(--model parametric\)"):
        parsed("--fix", "mu_c=1")


def _anisotropic_file(tmp_path) -> str:
    """An anisotropic Gaussian lobe (tests/helpers ANISO_TRUTH) at three scales, 25² px over ±0.3."""
    from helpers import ANISO_SCALES, ANISO_TRUTH, anisotropic_differences, gaussian

    import brdfscale as bs

    x = np.linspace(-0.3, 0.3, 25)
    u = np.stack(np.meshgrid(x, x), axis=-1)
    rng, images = np.random.default_rng(0), []
    for mu, d in zip(ANISO_SCALES, anisotropic_differences()):
        v = gaussian(u, ANISO_TRUTH["mean"], ANISO_TRUTH["C0"] + d, ANISO_TRUTH["amplitude"])
        s = 0.01 * v.max() + 1e-3
        values = v + s * rng.standard_normal(v.shape)
        images.append(bs.LobeImage(mu=mu, incident=[0, 0, 1.0], extent=0.3, values=values, sigma=np.full(v.shape, s)))
    path = tmp_path / "aniso.exr"
    exr.write_measurements(str(path), bs.MeasurementSet(tuple(images)))
    return str(path)


@pytest.mark.slow  # four fits compiled afresh: ≈ 70 s on 2 cores
def test_compare_reports_the_model_the_data_prefer(tmp_path, capsys):
    """--compare on anisotropic Gaussian lobes: the table (AIC, BIC) printed and in fit.json's
    model.comparison; the report is the anisotropic model's (smallest BIC), its exit status its
    verdict (ok: exit 0)."""
    out = tmp_path / "F"
    argv = ["--no-compilation-cache", "fit", _anisotropic_file(tmp_path), "--out", str(out), "--compare"]
    code = main([*argv, "--steps", "0", "--starts", "2", "--no-progress"])
    printed = capsys.readouterr().out
    doc = json.loads((out / "fit.json").read_text())
    comparison = doc["model"]["comparison"]
    assert comparison["preferred"] == {"bic": "anisotropic", "aic": "anisotropic"}
    assert comparison["reported"] == "anisotropic" and doc["model"]["kind"] == "anisotropic"
    rows = {r["model"]: r for r in comparison["rows"]}
    assert set(rows) == {"isotropic", "anisotropic", "anisotropic:student_t", "anisotropic:mixture", "anisotropic_law"}
    assert rows["isotropic"]["delta_bic"] > 10 and rows["anisotropic"]["delta_bic"] == 0
    assert doc["optimisation"]["reduced_chi2"] * (rows["anisotropic"]["n"] - 12) == pytest.approx(
        rows["anisotropic"]["chi2"], rel=1e-9
    )
    assert "preferred: anisotropic (BIC), anisotropic (AIC)" in printed
    assert code == {"ok": 0, "inadequate": 5, "not_converged": 6}[doc["outcome"]["status"]] == 0


@pytest.mark.slow  # one fit and two NUTS runs compiled afresh: 30–120 s on 2 shared cores
def test_a_chain_too_short_to_converge_exits_6_and_the_default_draws_exit_0(tmp_path, capsys):
    """An adequate fit sampled with NUTS: 5 draws per chain cannot reach ESS_bulk ≥ 400, so the
    report says not_converged, names the criterion, and the command exits 6; the default sampler (auto) and draws
    (``--steps`` not given: the chosen sampler's own, brdfscale.choices.SAMPLE) pass the same check: exit 0."""
    path = _simulated_file(tmp_path, "beckmann", 3)
    fit = ["fit", "--model", "parametric", "--starts", "2", "--no-progress", path, "--out"]
    assert main([*fit, str(tmp_path / "short"), "--sampler", "nuts", "--steps", "5"]) == 6
    printed = capsys.readouterr()
    assert printed.err.startswith("brdfscale fit: not converged: ") and "ESS_bulk < 400" in printed.err
    doc = json.loads((tmp_path / "short" / "fit.json").read_text())
    assert doc["outcome"]["status"] == "not_converged" and doc["mcmc"]["steps"] == SAMPLE.gradient_warmup + 5
    assert main([*fit, str(tmp_path / "default")]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((tmp_path / "default" / "fit.json").read_text())
    chosen = doc["mcmc"]["chosen_by"]
    assert chosen["name"] == "auto" and doc["mcmc"]["sampler"] == chosen["chose"]
    own = {"imh": SAMPLE.imh_steps, "nuts": SAMPLE.gradient_warmup + SAMPLE.gradient_steps}
    assert doc["mcmc"]["steps"] == own[chosen["chose"]]
    assert doc["mcmc"]["status"] == "converged" and doc["outcome"]["status"] == "ok"
    assert f"  {chosen['chose']} (auto: Pareto k̂ of its proposal's weights {chosen['pareto_k']:.2f} " in printed


@pytest.mark.slow  # one fit and three IMH runs compiled afresh: ≈ 30 s on 2 cores
def test_a_time_limit_exits_6_and_the_same_command_continues_the_chain(tmp_path, capsys):
    """--time-limit: the sampling ends after two steps (the limit passed during the fit), the report says so
    (mcmc.stopped, status not converged) and the command exits 6 with one line naming the limit; the same command
    run again resumes the report, continues the chain from DIR/chain.h5 to the steps asked, and ends as an unlimited
    run does."""
    path = _simulated_file(tmp_path, "beckmann", 3)
    fit = ["fit", "--model", "parametric", "--starts", "2", "--no-progress", "--sampler", "imh", path, "--out"]
    out = tmp_path / "limited"
    assert main([*fit, str(out), "--time-limit", "0.001"]) == 6
    printed = capsys.readouterr()
    last = printed.err.strip().splitlines()[-1]  # (ArviZ may warn first, on its import)
    assert last.startswith("brdfscale fit: not converged: ") and "time limit of 0.001 s reached" in last
    doc = json.loads((out / "fit.json").read_text())
    assert doc["mcmc"]["stopped"] == {"time_limit_s": 0.001, "steps": 2, "steps_asked": SAMPLE.imh_steps}
    assert doc["outcome"]["status"] == "not_converged"
    assert main([*fit, str(out)]) == 0  # no --force: the report in progress resumes, the chain continues
    printed = capsys.readouterr().out
    assert "its sampling stopped at the time limit after" in printed and "continues" in printed
    doc = json.loads((out / "fit.json").read_text())
    assert doc["mcmc"]["stopped"] is None and doc["mcmc"]["steps"] == SAMPLE.imh_steps
    assert main([*fit, str(tmp_path / "whole")]) == 0
    whole = json.loads((tmp_path / "whole" / "fit.json").read_text())
    assert whole["mcmc"]["summary"] == doc["mcmc"]["summary"]  # the continued chain is the unlimited run's
    assert main([*fit, str(out)]) == 2  # a complete report is refused as before


def test_the_undetermined_combinations_printed_are_capped_and_the_rest_counted():
    from brdfscale._cli._fit import SHOWN_UNDETERMINED, undetermined_lines

    items = [{"combination": f"1.00·log base[0,{i}]"} for i in range(SHOWN_UNDETERMINED + 3)]
    lines = undetermined_lines(items)
    assert lines[:-1] == [f"  not determined by the data: 1.00·log base[0,{i}]" for i in range(SHOWN_UNDETERMINED)]
    assert (
        lines[-1].startswith("  … and 3 more combinations") and "identifiability.undetermined_combinations" in lines[-1]
    )
    assert undetermined_lines(items[:2]) == [f"  not determined by the data: 1.00·log base[0,{i}]" for i in range(2)]
