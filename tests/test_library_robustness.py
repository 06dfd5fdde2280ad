"""`brdfscale fit-library` in a careless world (issue 34): damaged indices (MeasurementFileError)
and output directories refused in one line (exit 2) and left as they were; a material whose report was damaged after
the fact fitted again, equal to its first fit, and said so; a measurement file named twice
refused; hidden entries listed; a full disk while writing the index stops the run with the
previous index in place; a `kill -9` of a driver running Ray workers leaves no Ray process of its
run behind (slow). The fuzz family of experiments/_fuzz_library.py is run by
tests/test_experiments_smoke.py (slow)."""

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import brdfscale._files
from brdfscale import choices, InvalidInputError, library, MeasurementFileError, OutputWriteError
from brdfscale._watchdog import alive, descendants
from tests.helpers import run_cli, write_library


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ARGS = ["--starts", "1", "--batch", "1", "--no-progress"]


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdfscale fit-library: error: "), err
    return lines[0]


def _fit(out, name) -> dict:
    with open(os.path.join(out, "materials", name, "fit.json")) as f:
        return json.load(f)


def _inodes(out) -> dict:
    base = os.path.join(out, "materials")
    return {
        n: os.stat(os.path.join(base, n, "fit.json")).st_ino
        for n in os.listdir(base)
        if not n.startswith(".") and os.path.exists(os.path.join(base, n, "fit.json"))
    }


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A library of two materials and its complete, uninterrupted fit (the reference)."""
    base = tmp_path_factory.mktemp("library")
    write_library(str(base / "lib"), 2)
    code, out, err = run_cli(["fit-library", str(base / "lib"), "--out", str(base / "reference"), *ARGS])
    assert code == 0, out + err
    return base


@pytest.fixture
def copy(fitted, tmp_path):
    """A fresh copy of the reference output, and the command that continues it."""
    out = tmp_path / "out"
    shutil.copytree(fitted / "reference", out)
    return out, ["fit-library", str(fitted / "lib"), "--out", str(out), *ARGS]


def _edit(out, change):
    path = out / library.INDEX
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


DAMAGED = {
    "a list": lambda out: (out / library.INDEX).write_text("[]"),
    "null": lambda out: (out / library.INDEX).write_text("null"),
    "empty": lambda out: (out / library.INDEX).write_text(""),
    "truncated": lambda out: (out / library.INDEX).write_text((out / library.INDEX).read_text()[:57]),
    "not UTF-8": lambda out: (out / library.INDEX).write_bytes(b'{"format": 1, "spec": "\xff\xfe"}'),
    "nested 100 000 deep": lambda out: (out / library.INDEX).write_text("[" * 100_000 + "]" * 100_000),
    "no spec": lambda out: _edit(out, lambda d: d.pop("spec")),
    "spec a list": lambda out: _edit(out, lambda d: d.update(spec=[1])),
    "no runs": lambda out: _edit(out, lambda d: d.pop("runs")),
    "a run not an object": lambda out: _edit(out, lambda d: d["runs"].append(3)),
    "materials a list": lambda out: _edit(out, lambda d: d.update(materials=[])),
    "format 2": lambda out: _edit(out, lambda d: d.update(format=2)),
    "a material without source": lambda out: _edit(out, lambda d: d["materials"]["material_001"].pop("source")),
    "a source not a string": lambda out: _edit(out, lambda d: d["materials"]["material_000"].update(source=7)),
    "an unknown status": lambda out: _edit(out, lambda d: d["materials"]["material_000"].update(status="fine")),
    "attempts negative": lambda out: _edit(out, lambda d: d["materials"]["material_000"].update(attempts=-1)),
    "attempts true": lambda out: _edit(out, lambda d: d["materials"]["material_000"].update(attempts=True)),
    "failed without error": lambda out: _edit(out, lambda d: d["materials"]["material_000"].update(status="failed")),
    "a material not an object": lambda out: _edit(out, lambda d: d["materials"].update(other="x")),
}


@pytest.mark.parametrize("damage", sorted(DAMAGED))
def test_a_damaged_index_is_refused_in_one_line_and_left_as_it_was(copy, damage):
    out, command = copy
    DAMAGED[damage](out)
    before, inodes = (out / library.INDEX).read_bytes(), _inodes(out)
    code, _, err = run_cli(command)
    assert code == 2
    line = _one_line(err)
    assert str(out / library.INDEX) in line and "unreadable library index" in line and "move it away" in line
    assert (out / library.INDEX).read_bytes() == before and _inodes(out) == inodes


@pytest.mark.parametrize("damage", ["truncated", "a list", "an unknown status"])
def test_a_damaged_index_is_a_damaged_file_not_a_bad_argument(fitted, copy, damage):
    """``fit_library`` raises MeasurementFileError for a damaged index (the class of a file that
    cannot be read as asked), not InvalidInputError (a bad argument); the command's status stays 2."""
    import jax

    jax.config.update("jax_enable_x64", True)
    out, _ = copy
    DAMAGED[damage](out)
    with pytest.raises(MeasurementFileError, match="unreadable library index") as caught:
        library.fit_library(fitted / "lib", out, spec=library.FitSpec(starts=1), batch=1, progress=False)
    assert not isinstance(caught.value, InvalidInputError)


@pytest.mark.parametrize("where", ["materials", "materials/material_001", "out"])
def test_an_output_path_that_is_not_a_directory_is_refused_in_one_line(copy, where):
    out, command = copy
    target = out if where == "out" else out / where
    shutil.rmtree(target)
    target.write_text("not a directory")
    code, _, err = run_cli(command)
    assert code == 2
    line = _one_line(err)
    assert str(target) in line and "not a directory" in line
    assert target.read_text() == "not a directory"


def _drop_listed_table(directory):
    tables = _fit_doc(directory)["tables"]
    assert isinstance(tables, list) and tables  # evolved_lobes.exr: a file the report lists
    os.remove(os.path.join(directory, os.path.basename(tables[0])))


def _fit_doc(directory):
    with open(os.path.join(directory, "fit.json")) as f:
        return json.load(f)


REPORT_DAMAGE = {
    "deleted": (lambda d: os.remove(d / "fit.json"), "no fit.json"),
    "truncated": (lambda d: (d / "fit.json").write_text((d / "fit.json").read_text()[:100]), "fit.json is unreadable"),
    "a list": (lambda d: (d / "fit.json").write_text("[]"), "fit.json is not a report"),
    "a listed file gone": (_drop_listed_table, "evolved_lobes.exr, listed in fit.json, is missing"),
}


@pytest.mark.parametrize("damage", sorted(REPORT_DAMAGE))
def test_a_material_whose_report_was_damaged_is_fitted_again_and_the_run_says_so(fitted, copy, damage):
    out, command = copy
    spoil, said = REPORT_DAMAGE[damage]
    untouched = _inodes(out)["material_000"]
    spoil(out / "materials" / "material_001")
    code, text, err = run_cli(command)
    assert code == 0, text + err
    assert f"{out / 'materials' / 'material_001'}: {said}" in text and "fitting material_001 again" in text
    assert "fitted this run  1" in text and _inodes(out)["material_000"] == untouched
    again, first = _fit(out, "material_001"), _fit(fitted / "reference", "material_001")
    np.testing.assert_allclose(again["optimisation"]["theta"], first["optimisation"]["theta"], rtol=1e-12)
    assert again["optimisation"]["chi2"] == pytest.approx(first["optimisation"]["chi2"], rel=1e-12)
    with open(out / library.INDEX) as f:
        entry = json.load(f)["materials"]["material_001"]
    assert entry["status"] == "done" and entry["attempts"] == 2 and "damaged" in entry["note"]
    assert not [n for n in os.listdir(out / "materials") if n.endswith(".partial")]


def test_a_partial_directory_left_beside_a_complete_report_goes(copy):
    out, command = copy
    (out / "materials" / ".material_001.partial").mkdir()
    (out / "materials" / ".material_001.partial" / "fit.json").write_text("{")  # a killed attempt's remains
    inodes = _inodes(out)
    code, text, err = run_cli(command)
    assert code == 0 and "fitted this run  0" in text, text + err
    assert not (out / "materials" / ".material_001.partial").exists() and _inodes(out) == inodes


def test_a_measurement_file_named_twice_is_refused_in_one_line(fitted, tmp_path):
    one = str(fitted / "lib" / "material_000.exr")
    os.symlink(one, tmp_path / "link.exr")
    for sources in ([one, one], [str(fitted / "lib"), one], [one, str(tmp_path / "link.exr")]):
        code, _, err = run_cli(["fit-library", *sources, "--out", str(tmp_path / "out"), *ARGS])
        assert code == 2
        line = _one_line(err)
        assert "named twice" in line and one in line
        assert not (tmp_path / "out" / library.INDEX).exists()


def test_hidden_entries_are_listed_in_one_line(tmp_path):
    (tmp_path / "lib" / ".cache").mkdir(parents=True)
    (tmp_path / "lib" / "damaged.exr").write_bytes(b"v/1\x01" + bytes(200))  # fails at once: no fit needed
    (tmp_path / "lib" / ".draft.exr").write_bytes(b"")
    (tmp_path / "lib" / ".cache" / "old.exr").write_bytes(b"")
    (tmp_path / "lib" / ".notes").write_bytes(b"")  # not a measurement file: not listed
    code, text, _ = run_cli(["fit-library", str(tmp_path / "lib"), "--out", str(tmp_path / "out"), *ARGS])
    assert code == 4  # the damaged file failed; the library ran
    lines = [line for line in text.splitlines() if line.startswith("  skipped")]
    cache, draft = os.path.join(tmp_path, "lib", ".cache") + os.sep, os.path.join(tmp_path, "lib", ".draft.exr")
    assert lines == [f"  skipped 2 hidden entries (names starting with '.'; rename to include): {cache}, {draft}"]


def test_a_full_disk_while_writing_the_index_leaves_the_previous_index(copy, monkeypatch):
    out, command = copy
    before = (out / library.INDEX).read_bytes()

    def full(step, tmp):
        if step == "fsync" and os.path.basename(tmp).startswith(f".{library.INDEX}"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(brdfscale._files, "_fault", full)
    options = json.loads(before)["spec"]  # the command's options
    spec = library.FitSpec(**{**options, "fixed": tuple(options["fixed"].items())})
    with pytest.raises(OutputWriteError, match="disk full") as raised:
        library.fit_library(command[1], out, spec=spec, batch=1, progress=False)
    assert raised.value.path == str(out / library.INDEX) and raised.value.disk_full
    code, _, err = run_cli(command)
    assert code == 8 and "disk full" in _one_line(err)
    assert (out / library.INDEX).read_bytes() == before
    assert [n for n in os.listdir(out) if n.startswith(f".{library.INDEX}")] == []  # no temporary left
    monkeypatch.undo()
    code, text, err = run_cli(command)  # with space again: the library is complete, nothing refitted
    assert code == 0 and "fitted this run  0" in text, text + err


def test_a_full_disk_while_a_report_is_written_stops_the_run_and_the_rerun_completes(fitted, copy, monkeypatch):
    out, command = copy
    os.remove(out / "materials" / "material_001" / "fit.json")
    before = (out / library.INDEX).read_bytes()

    def full(step, tmp):
        if step == "fsync" and os.path.basename(tmp).startswith(".fit.json"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(brdfscale._files, "_fault", full)
    code, _, err = run_cli(command)
    line = _one_line(err)
    assert code == 8 and "disk full" in line and "fit.json" in line
    index = json.loads((out / library.INDEX).read_bytes())  # whole: the run's start, recorded before the fit
    assert len(index["runs"]) == len(json.loads(before)["runs"]) + 1
    assert index["materials"]["material_001"]["status"] == "pending"
    assert not (out / "materials" / "material_001" / "fit.json").exists()  # no report pretends to be whole
    monkeypatch.undo()
    code, text, err = run_cli(command)
    assert code == 0 and "fitted this run  1" in text, text + err
    again, first = _fit(out, "material_001"), _fit(fitted / "reference", "material_001")
    np.testing.assert_allclose(again["optimisation"]["theta"], first["optimisation"]["theta"], rtol=1e-12)


# -- a driver killed with Ray workers ---------------------------------------------------------------


@pytest.mark.slow  # a Ray instance and worker processes importing JAX: tens of seconds on 2 cores
def test_sigkill_of_a_driver_with_ray_workers_leaves_no_ray_process(fitted, tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "out"
    command = [sys.executable, "-m", "brdfscale", "fit-library", str(fitted / "lib"), "--out", str(out)]
    driver = subprocess.Popen(
        [*command, *ARGS, "--workers", "2"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    seen: dict = {}
    try:
        deadline = time.monotonic() + 300
        # until a worker is in its task (its material's partial directory or report exists)
        while not (out / "materials").is_dir() or not os.listdir(out / "materials"):
            assert time.monotonic() < deadline and driver.poll() is None, "the library did not start"
            seen.update(descendants(driver.pid))
            time.sleep(0.05)
        seen.update(descendants(driver.pid))
        assert any(b"raylet" in open(f"/proc/{p}/cmdline", "rb").read() for p in alive(seen))
    finally:
        os.kill(driver.pid, signal.SIGKILL)
        driver.wait()
    deadline = time.monotonic() + 10
    while alive(seen) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = alive(seen)
    for pid in left:  # clean up before failing
        os.kill(pid, signal.SIGKILL)
    assert not left, f"{len(left)} process(es) of the killed run still running after 10 s"
    # the rerun on Ray too: it ends with its true status (the watchdog once took its own driver, waiting for it
    # after ray.shutdown(), for one of the run's processes: exit -15), and leaves nothing behind either
    rerun = subprocess.Popen(
        [*command, *ARGS, "--workers", "2"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    again: dict = {}
    while rerun.poll() is None:
        again.update(descendants(rerun.pid))
        time.sleep(0.05)
    assert rerun.returncode == 0, rerun.communicate()[1][-2000:]
    deadline = time.monotonic() + 10
    while alive(again) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(again)
    for name in ("material_000", "material_001"):
        np.testing.assert_allclose(
            _fit(out, name)["optimisation"]["theta"],
            _fit(fitted / "reference", name)["optimisation"]["theta"],
            rtol=1e-9,
        )


def test_an_index_recorded_before_starts_auto_is_continued():
    """An index written before ``starts="auto"`` recorded the count (8): the default spec ("auto") continues it for
    every model whose own count is 8, and is refused naming starts=8 for the anisotropic non-parametric model (1);
    any other difference is named as before."""
    from brdfscale.library._run import spec_differences

    old = {**library.FitSpec().to_json(), "starts": 8}
    assert spec_differences(old, library.FitSpec()) == ""
    assert spec_differences({**old, "model": "parametric"}, library.FitSpec(model="parametric")) == ""
    assert spec_differences(old, library.FitSpec(starts=8)) == ""
    assert spec_differences(old, library.FitSpec(starts=3)) == "starts=8"
    nonparametric = {**old, "model": "nonparametric_anisotropic"}
    assert spec_differences(nonparametric, library.FitSpec(model="nonparametric_anisotropic")) == "starts=8"
    assert spec_differences({"model": "parametric"}, library.FitSpec()) == "model='parametric'"


def test_a_model_not_sampled_by_default_keeps_laplace_unless_steps_are_given():
    """FitSpec.not_sampled_because, the rule of ``brdfscale fit`` and fit_library: the anisotropic non-parametric
    model (``sampled_by_default`` False, looked up through the one name → class table) is not sampled when a
    sampler is asked for without steps, and the reason says how to sample it; with steps, or for any other model,
    the rule is the inadequacy one (here switched off by sample_inadequate, so no fit is needed)."""
    assert not library.model_class("nonparametric_anisotropic").sampled_by_default
    assert all(library.model_class(m).sampled_by_default for m in choices.MODELS if m != "nonparametric_anisotropic")
    spec = library.FitSpec(model="nonparametric_anisotropic", sampler="auto", sample_inadequate=True)
    reason = spec.not_sampled_because(None, None)
    assert "--steps N" in reason and "Laplace" in reason and spec.not_sampled_by_default == reason
    assert library.FitSpec(sampler="auto").not_sampled_by_default is None
    assert library.FitSpec(model="nonparametric_anisotropic", sampler=None).not_sampled_because(None, None) is None
    given = library.FitSpec(model="nonparametric_anisotropic", sampler="nuts", steps=50, sample_inadequate=True)
    assert given.not_sampled_because(None, None) is None
    assert library.FitSpec(sampler="auto", sample_inadequate=True).not_sampled_because(None, None) is None
