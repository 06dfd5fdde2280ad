"""``brdfscale synth --instrument raytraced``: the ray-traced gonioreflectometer on the command line (issue 32 item 1).

A missing Mitsuba or LLVM is simulated (the module made unimportable; Dr.Jit made to find no LLVM backend): the
command must then say in one line what to install and exit with status 2, before it writes anything.
"""

import importlib.util
import subprocess
import sys

import numpy as np
import pytest

import brdfscale._cli as cli
from brdfscale import exr


@pytest.fixture(autouse=True)
def _only_existing_subcommands(monkeypatch):
    """Register only the subcommand modules that exist (another module may still be missing)."""
    present = tuple(n for n in cli._SUBCOMMANDS if importlib.util.find_spec(f"brdfscale._cli._{n}") is not None)
    monkeypatch.setattr(cli, "_SUBCOMMANDS", present)


def _argv(out, *extra):
    return ["synth", "gaussian", "--out", str(out), "--size", "32", "--scales", "4,16", "--pixels", "9", *extra]


def _one_line_error(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdfscale synth: error: "), captured.err
    assert "Traceback" not in captured.err
    return lines[0]


def test_missing_mitsuba_is_named_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # `import mitsuba` now raises ImportError
    out = tmp_path / "set.exr"
    assert cli.main(_argv(out, "--instrument", "raytraced")) == 2
    line = _one_line_error(capsys)
    assert "Mitsuba 3 is not installed" in line and 'pip install "brdfscale[render]"' in line
    assert not out.exists()


def test_missing_llvm_is_named_in_one_line(tmp_path, capsys, monkeypatch):
    dr = pytest.importorskip("drjit")
    pytest.importorskip("mitsuba")
    monkeypatch.setattr(dr, "has_backend", lambda backend: False)  # as on a machine without libLLVM
    out = tmp_path / "set.exr"
    assert cli.main(_argv(out, "--instrument", "raytraced", "--variant", "llvm_ad_rgb")) == 2
    line = _one_line_error(capsys)
    assert "Dr.Jit found no LLVM library" in line and "libllvm19" in line
    assert not out.exists()


@pytest.mark.parametrize(
    "extra, named",
    [
        (["--rays", "100"], "--rays: an option of --instrument raytraced only"),
        (["--bounces", "2", "--variant", "scalar_rgb"], "--bounces and --variant: options of --instrument raytraced"),
        (["--instrument", "raytraced", "--noise", "poisson:100"], "--noise: an option of --instrument facets only"),
        (["--instrument", "raytraced", "--weighting", "projected_area"], "--weighting: an option of --instrument"),
        (["--instrument", "raytraced", "--micro", "ggx"], "--micro names the pixel facets' distribution"),
        (["--workers", "2"], "--workers: an option of --instrument raytraced only"),
    ],
)
def test_options_of_the_other_instrument_are_refused(tmp_path, capsys, monkeypatch, extra, named):
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # refused before Mitsuba is asked for
    out = tmp_path / "set.exr"
    assert cli.main(_argv(out, *extra)) == 2
    assert named in _one_line_error(capsys)
    assert not out.exists()


def test_bad_numbers_are_refused_by_argparse(tmp_path, capsys):
    for extra in (["--rays", "0"], ["--bounces", "65"], ["--instrument", "pinhole"]):
        with pytest.raises(SystemExit) as exc:
            cli.main(_argv(tmp_path / "set.exr", *extra))
        assert exc.value.code == 2
        assert extra[0] in capsys.readouterr().err


def test_raytraced_measurement_is_written_and_deterministic(tmp_path, capsys):
    """A tiny measurement (32² field, 2 scales, 4000 rays): an EXR set whose σ is the MC error, the same for a seed."""
    pytest.importorskip("mitsuba")
    argv = ["--instrument", "raytraced", "--rays", "4000", "--bounces", "2", "--seed", "3", "--incident", "30"]
    first, second = tmp_path / "a.exr", tmp_path / "b.exr"
    assert cli.main(_argv(first, *argv)) == 0
    assert cli.main(_argv(second, *argv)) == 0
    assert "wrote" in capsys.readouterr().out
    a, b = exr.read_measurements(first), exr.read_measurements(second)
    assert sorted({p.mu for p in a.images}) == [4.0, 16.0]
    np.testing.assert_allclose(a.images[0].incident, [0.5, 0.0, np.sqrt(0.75)], atol=1e-7)
    for pa, pb in zip(a.images, b.images, strict=True):
        assert pa.sigma is not None and np.all(np.asarray(pa.sigma) >= 0)
        np.testing.assert_array_equal(np.asarray(pa.values), np.asarray(pb.values))
    assert a.metadata["command"].endswith("--instrument raytraced --rays 4000 --bounces 2")
    assert a.metadata["seed"] == 3


@pytest.mark.slow  # a local Ray instance (~30 s on the shared 2 cores)
def test_raytraced_measurement_on_ray_workers_is_the_same_file(tmp_path):
    """--workers 2: the images traced as tasks on a local Ray instance give the in-process file's images bit for bit
    (and the same recorded command: where it ran is no part of the result)."""
    pytest.importorskip("mitsuba")
    pytest.importorskip("ray")
    argv = ["--instrument", "raytraced", "--rays", "2000", "--seed", "3", "--incident", "30"]
    here, there = tmp_path / "a.exr", tmp_path / "b.exr"
    # both as commands of their own, as a user runs them (this process runs JAX in float64, the command in float32):
    # a Ray driver is never a pytest worker (a worker that had hosted one crashed later in the slow step)
    for out, extra in ((here, []), (there, ["--workers", "2"])):
        command = [sys.executable, "-m", "brdfscale", "--no-compilation-cache", *_argv(out, *argv, *extra)]
        run = subprocess.run(command, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-3000:]
    a, b = exr.read_measurements(here), exr.read_measurements(there)
    for pa, pb in zip(a.images, b.images, strict=True):
        np.testing.assert_array_equal(np.asarray(pa.values), np.asarray(pb.values))
        np.testing.assert_array_equal(np.asarray(pa.sigma), np.asarray(pb.sigma))
    assert a.metadata["command"] == b.metadata["command"]
