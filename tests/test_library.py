"""brdfscale.library and `brdfscale fit-library`: a library in-process and on a local Ray instance
with 2 workers (equal results), a corrupt file reported and skipped, a driver killed mid-library
and a worker killed mid-task, each material fitted exactly once, options and lock checks."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from brdfscale import InvalidInputError, library
from brdfscale._cli import main
from brdfscale.files import exclusive
from tests.helpers import write_library


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def small_library(tmp_path_factory):
    directory = tmp_path_factory.mktemp("library")
    write_library(str(directory), 5)
    with open(directory / "material_999.exr", "wb") as f:  # a damaged file among good ones
        f.write(b"v/1\x01" + bytes(200))
    return directory


def _command(*arguments: str) -> list[str]:
    """``python -m brdfscale fit-library ARGUMENTS``: a driver in a process of its own."""
    return [sys.executable, "-m", "brdfscale", "fit-library", *arguments]


def _index(out):
    with open(os.path.join(out, library.INDEX)) as f:
        return json.load(f)


def _fit_json(out, name):
    with open(os.path.join(out, "materials", name, "fit.json")) as f:
        return json.load(f)


def _inodes(out):
    base = os.path.join(out, "materials")
    return {n: os.stat(os.path.join(base, n, "fit.json")).st_ino for n in os.listdir(base) if not n.startswith(".")}


@pytest.mark.slow  # ~16 s; tests/test_library_robustness.py keeps damaged inputs and resuming in the default suite
def test_library_in_process_reports_the_corrupt_file_and_resumes(small_library, tmp_path, capsys):
    out = str(tmp_path / "out")
    status = main(["fit-library", str(small_library), "--out", out, "--batch", "2", "--starts", "2", "--no-progress"])
    text = capsys.readouterr().out
    assert status == 4, text  # finished, one material failed
    index = _index(out)
    states = {n: m["status"] for n, m in index["materials"].items()}
    assert states == {**{f"material_{i:03d}": "done" for i in range(5)}, "material_999": "failed"}
    assert "MeasurementFileError" in index["materials"]["material_999"]["error"]
    assert "failed: material_999" in text and "fitted this run  5" in text
    assert index["spec"]["starts"] == 2 and index["runs"][0]["done"] == 5
    fit = _fit_json(out, "material_000")
    assert fit["optimisation"]["status"] == "converged" and 0.8 < fit["optimisation"]["reduced_chi2"] < 1.2
    assert sorted(os.listdir(os.path.join(out, "materials", "material_000"))) == [
        ".brdfscale.lock",
        "evolved_lobes.exr",
        "fit.json",
    ]
    before = _inodes(out)
    # run again: nothing refitted, the damaged file tried again and still reported
    assert (
        main(["fit-library", str(small_library), "--out", out, "--batch", "2", "--starts", "2", "--no-progress"]) == 4
    )
    assert _inodes(out) == before
    index = _index(out)
    assert all(m["attempts"] == 1 for n, m in index["materials"].items() if n != "material_999")
    assert index["materials"]["material_999"]["attempts"] == 2 and len(index["runs"]) == 2
    # other options into the same library: refused, naming what differs
    with pytest.raises(InvalidInputError, match="other options.*starts=2"):
        library.fit_library(small_library, out, spec=library.FitSpec(starts=3), progress=False)
    assert main(["fit-library", str(small_library), "--out", out, "--no-progress"]) == 2
    # a second run while one holds the directory: refused at once
    with exclusive(out, what="library directory"):
        code = subprocess.run(
            _command(str(small_library), "--out", out, "--starts", "2", "--batch", "2", "--no-progress"),
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=300,
        )
    assert code.returncode == 3 and "another run is writing this library directory" in code.stderr


def test_a_damaged_index_is_refused_not_overwritten(small_library, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / library.INDEX).write_text('{"format": 1, "materials": ')  # a truncated index
    assert main(["fit-library", str(small_library), "--out", str(out), "--no-progress"]) == 2
    assert "unreadable library index" in capsys.readouterr().err
    assert (out / library.INDEX).read_text() == '{"format": 1, "materials": '  # left as it was
    assert not (out / "materials" / "material_000").exists()


def test_fit_library_results_equal_fit_many(small_library, tmp_path):
    import jax

    from brdfscale import exr, fitting

    jax.config.update("jax_enable_x64", True)
    result = library.fit_library(
        [small_library / "material_001.exr", small_library / "material_003.exr"],
        tmp_path / "out",
        spec=library.FitSpec(model="parametric", starts=2),
        progress=False,
    )
    assert (result.done, result.failed, result.executor) == (2, 0, "process") and "fitted" in repr(result)
    data = [
        fitting.Dataset.from_measurements(exr.read_measurements(small_library / f"material_00{i}.exr")) for i in (1, 3)
    ]
    direct = fitting.fit_many(fitting.ParametricModel(), data, starts=2)
    for name, fit in zip(("material_001", "material_003"), direct):
        np.testing.assert_allclose(_fit_json(tmp_path / "out", name)["optimisation"]["theta"], fit.theta, rtol=1e-12)


@pytest.mark.slow
def test_library_samples_with_nuts_batched_equal_to_sample_per_material(small_library, tmp_path, capsys):
    """--sampler nuts: the task's materials sampled together (fitting.sample_many), each report's
    chain summary that of fitting.sample on the material alone, bit for bit.

    The model is named (``--model parametric``) and checked in the report: run with the default
    model (anisotropic since issue 31) this test once compared the library's anisotropic chain
    with a parametric one alone, and took the different posterior for a 4th-digit regression. The
    parametric model is the one whose stacked program XLA compiles as the single one (fitting.sample_many's
    "What is equal"; the anisotropic model's agreement is to rounding, tests/test_sample_many_models.py)."""
    import jax

    from brdfscale import exr, fitting

    jax.config.update("jax_enable_x64", True)
    # materials whose lobes are resolved at every scale: material_001's is not (0.88 image pixels at μ0), and a fit
    # undetermined before sampling is not sampled (FitSpec.not_sampled_because)
    sources = [str(small_library / "material_000.exr"), str(small_library / "material_003.exr")]
    out = tmp_path / "out"
    argv = ["fit-library", *sources, "--out", str(out), "--model", "parametric", "--starts", "2"]
    argv += ["--steps", "30", "--sampler", "nuts", "--chains", "2", "--no-progress"]
    assert main(argv) == 0, capsys.readouterr().out
    spec = _index(out)["spec"]
    assert (spec["model"], spec["sampler"], spec["chains"], spec["steps"], spec["seed"]) == (
        "parametric",
        "nuts",
        2,
        30,
        0,
    )
    data = [fitting.Dataset.from_measurements(exr.read_measurements(path)) for path in sources]
    model = fitting.ParametricModel()
    fits = fitting.fit_many(model, data, starts=2)
    for name, d, fit in zip(("material_000", "material_003"), data, fits):
        alone = fitting.sample(fitting.Problem(model, d), fit, sampler="nuts", chains=2, steps=30, progress=False)
        doc = _fit_json(out, name)
        assert doc["optimisation"]["theta_names"] == list(alone.names)  # the same model's posterior
        report = doc["mcmc"]
        assert report["sampler"] == "nuts" and report["steps"] == alone.chain.shape[0] == fitting.NUTS().warmup + 30
        assert report["burn_in"] == alone.burn and report["warmup"]["steps"] == alone.warmup["steps"]
        assert report["summary"].keys() == alone.summary().keys()
        for quantity, row in alone.summary().items():
            assert report["summary"][quantity] == row, quantity  # the same chain, bit for bit


def test_which_samplers_a_library_batches_and_which_it_runs_per_material():
    """FitSpec.batched asks the sampler (check_batched): NUTS and HMC run the task's materials in one program,
    emcee, IMH and auto one material after another (each checkpointed); no sampler, neither."""
    for name, batched in [("nuts", True), ("hmc", True), ("emcee", False), ("imh", False), ("auto", False)]:
        assert library.FitSpec(sampler=name).batched is batched, name
    assert library.FitSpec().batched is False


@pytest.mark.slow
def test_library_samples_with_auto_per_material(small_library, tmp_path, capsys):
    """--sampler auto (the command's default sampler) samples each material after its fit, checkpointed in its
    directory, and the report records the choice; once, the library sampled only with nuts, hmc and emcee, and
    --sampler imh wrote reports without a chain. A material whose lobe is not resolved (undetermined before
    sampling: FitSpec.not_sampled_because) is not sampled, and its report says why."""
    sources = [str(small_library / "material_000.exr"), str(small_library / "material_001.exr")]
    out = tmp_path / "out"
    argv = ["fit-library", *sources, "--out", str(out), "--model", "parametric", "--starts", "2"]
    argv += ["--steps", "200", "--sampler", "auto", "--chains", "2", "--no-progress"]
    assert main(argv) == 0, capsys.readouterr().out
    report = _fit_json(out, "material_000")["mcmc"]
    assert report["chosen_by"]["name"] == "auto" and report["sampler"] == report["chosen_by"]["chose"]
    assert report["chains"] == 2 and (out / "materials" / "material_000" / "chain.h5").exists()
    # material_001's lobe at μ0 is 0.88 image pixels wide: undetermined before sampling, so not sampled
    unresolved = _fit_json(out, "material_001")
    assert (
        unresolved["outcome"]["status"] == "undetermined"
        and not (out / "materials" / "material_001" / "chain.h5").exists()
    )
    assert unresolved["mcmc"]["status"].startswith("not sampled: the fit is undetermined before sampling")
    assert "0.88 image pixels wide" in unresolved["mcmc"]["status"]


@pytest.mark.slow  # three libraries of one material, each fitted and two sampled: ~40 s on 2 cores
def test_a_library_does_not_sample_an_inadequate_fit_unless_asked(tmp_path, capsys):
    """FitSpec's rule, as `brdfscale fit` applies it: GGX lobes fitted by the Beckmann model are inadequate before
    sampling, so neither the batched sampler (nuts: left out of fitting.sample_many) nor a per-material one (imh)
    samples them — the report's mcmc says why, no chain.h5 — and --sample-inadequate samples them all the same.
    An index written before the option existed (no sample_inadequate key) is continued, not refused."""
    from brdfscale import exr, fitting

    ggx = fitting.ParametricModel("ggx", "ggx")
    truth = dict(amplitude=1.0, alpha_lobe=0.1, alpha_max=0.3, mu_c=4.0, exponent=1.0)  # tests/test_fit_cli.py's
    mset = fitting.simulate(ggx, truth, (1.0, 4.0, 16.0), size=25, extent=0.5, noise=0.02, floor=1e-3, seed=3)
    source = tmp_path / "ggx.exr"
    exr.write_measurements(str(source), mset)
    base = ["fit-library", str(source), "--model", "parametric", "--starts", "2", "--chains", "2", "--no-progress"]
    for sampler in ("nuts", "imh"):
        out = tmp_path / sampler
        assert main([*base, "--out", str(out), "--sampler", sampler, "--steps", "20"]) == 0, capsys.readouterr().out
        doc = _fit_json(out, "ggx")
        assert doc["outcome"]["status"] == "inadequate"
        assert doc["mcmc"]["status"].startswith("not sampled: the model is inadequate before sampling"), sampler
        assert not (out / "materials" / "ggx" / "chain.h5").exists()
        assert _index(out)["spec"]["sample_inadequate"] is False
    out = tmp_path / "anyway"
    argv = [*base, "--out", str(out), "--sampler", "nuts", "--steps", "20", "--sample-inadequate"]
    assert main(argv) == 0
    doc = _fit_json(out, "ggx")
    assert doc["outcome"]["status"] == "inadequate" and doc["mcmc"]["sampler"] == "nuts"
    # an index without the key (written before the option): continued with the option's default, not refused
    index = _index(tmp_path / "nuts")
    del index["spec"]["sample_inadequate"]
    (tmp_path / "nuts" / library.INDEX).write_text(json.dumps(index))
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "nuts"), "--sampler", "nuts", "--steps", "20"]) == 0
    assert "other options" not in capsys.readouterr().out


def test_fit_spec_sample_inadequate_is_a_flag_recorded_in_the_index():
    assert library.FitSpec().sample_inadequate is False and library.FitSpec().to_json()["sample_inadequate"] is False
    assert library.FitSpec(sample_inadequate=True).to_json()["sample_inadequate"] is True


@pytest.mark.wrong_types
def test_fit_spec_refuses_a_sample_inadequate_that_is_not_a_flag():
    with pytest.raises(InvalidInputError, match="sample_inadequate must be True or False"):
        library.FitSpec(sample_inadequate="yes")  # type: ignore[arg-type]


def test_sources_are_named_uniquely_and_missing_ones_refused(tmp_path):
    (tmp_path / "a" / "b").mkdir(parents=True)
    (tmp_path / "c").mkdir()
    for p in ("a/x.exr", "a/b/x.exr", "a/.hidden.exr", "a/readme.txt", "c/x.exr"):
        (tmp_path / p).write_bytes(b"")
    names = [n for n, _ in library.find_materials([tmp_path / "a", tmp_path / "c" / "x.exr"])]
    assert names == ["x", "b__x", "x-2"]  # a directory's own files first, then its subdirectories
    with pytest.raises(InvalidInputError, match="named twice"):  # one file twice: tests/test_library_robustness.py
        library.find_materials([tmp_path / "a", tmp_path / "a" / "x.exr"])
    with pytest.raises(InvalidInputError, match="no such file"):
        library.find_materials([tmp_path / "nothing"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InvalidInputError, match="no measurement files"):
        library.find_materials([tmp_path / "empty"])


def _wait_for(condition, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def _done(out):
    base = os.path.join(out, "materials")
    return [n for n in os.listdir(base) if not n.startswith(".")] if os.path.isdir(base) else []


@pytest.mark.slow  # 27 s on 2 cores (a subprocess compiles its own programs): .ci/run's second step runs it
def test_a_driver_killed_mid_library_resumes_with_each_material_fitted_once(small_library, tmp_path):
    out = str(tmp_path / "out")
    command = _command(str(small_library), "--out", out, "--batch", "1", "--starts", "2", "--no-progress")
    driver = subprocess.Popen(
        command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    try:
        _wait_for(lambda: len(_done(out)) >= 2, 300, "two materials")
    finally:
        os.killpg(driver.pid, signal.SIGKILL)
        driver.wait()
    first = _inodes(out)
    assert 2 <= len(first) < 5
    rerun = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 4, rerun.stderr[-2000:]
    assert {n: i for n, i in _inodes(out).items() if n in first} == first  # not refitted
    index = _index(out)
    assert sorted(_done(out)) == [f"material_{i:03d}" for i in range(5)]
    assert not [n for n in os.listdir(os.path.join(out, "materials")) if n.endswith(".partial")]
    # each material fitted exactly once: one attempt each (those the killed driver finished but had not
    # yet indexed were found complete, not redone)
    for name in _done(out):
        entry = index["materials"][name]
        assert entry["status"] == "done" and entry.get("attempts", 0) <= 1, (name, entry)
    assert sum(index["materials"][n].get("attempts", 0) for n in _done(out)) == 5 - sum(
        "found complete" in index["materials"][n].get("note", "") for n in _done(out)
    )


@pytest.mark.slow
def test_ray_with_2_workers_equals_in_process_and_survives_a_killed_worker(small_library, tmp_path):
    pytest.importorskip("ray")
    local, ray_out = str(tmp_path / "local"), str(tmp_path / "ray")
    assert (
        main(["fit-library", str(small_library), "--out", local, "--batch", "2", "--starts", "2", "--no-progress"]) == 4
    )
    # Ray: 2 workers, figures on (so a material's report takes seconds: time to kill its worker mid-task)
    command = _command(str(small_library), "--out", ray_out, "--batch", "2", "--starts", "2", "--workers", "2")
    command += ["--figures", "--no-progress"]
    driver = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    try:
        partial = os.path.join(ray_out, "materials")

        def holder():
            if not os.path.isdir(partial):
                return None
            for n in os.listdir(partial):
                record = os.path.join(partial, n, ".brdfscale.lock.holder.json")
                if n.endswith(".partial") and os.path.exists(record):
                    try:
                        with open(record) as f:
                            return json.load(f)["pid"]
                    except (OSError, ValueError):
                        return None
            return None

        _wait_for(lambda: holder() is not None, 300, "a worker writing a material")
        killed = holder()
        os.kill(killed, signal.SIGKILL)  # the Ray worker in the middle of its task
        stdout, stderr = driver.communicate(timeout=900)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert driver.returncode == 4, stderr[-3000:]
    assert killed != driver.pid
    index = _index(ray_out)
    assert sorted(_done(ray_out)) == [f"material_{i:03d}" for i in range(5)]
    assert not [n for n in os.listdir(os.path.join(ray_out, "materials")) if n.endswith(".partial")]
    assert index["runs"][0]["executor"] == "ray" and index["materials"]["material_999"]["status"] == "failed"
    for i in range(5):
        name = f"material_{i:03d}"
        a, b = _fit_json(local, name), _fit_json(ray_out, name)
        np.testing.assert_allclose(a["optimisation"]["theta"], b["optimisation"]["theta"], rtol=1e-9)
        assert os.path.exists(os.path.join(ray_out, "materials", name, "corner.png"))
