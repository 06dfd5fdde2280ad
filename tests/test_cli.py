"""The ``brdfscale`` command: help, version, the example."""

import subprocess
import sys

import pytest

import brdfscale
from brdfscale._cli import main


def test_help_and_version(capsys):
    assert main([]) == 0
    assert "example" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert brdfscale.__version__ in capsys.readouterr().out


@pytest.mark.slow  # 5–60 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_example_writes_png_and_refuses_to_overwrite(tmp_path, capsys):
    assert main(["example", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    png = tmp_path / "example.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "radial" in out and "no BRDF exists at this scale" in out
    assert main(["example", "--out", str(tmp_path)]) == 2
    assert "--force" in capsys.readouterr().err


def test_console_entry_point_runs():
    res = subprocess.run([sys.executable, "-m", "brdfscale", "--help"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and "COMMAND" in res.stdout


def _run_command(*args, env_extra, cwd):
    import os

    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE", "BRDFSCALE_"))
    }
    env.update(env_extra)
    return subprocess.run(
        [sys.executable, "-m", "brdfscale", *args], capture_output=True, text=True, timeout=300, env=env, cwd=cwd
    )


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.compilation_cache
def test_command_keeps_compiled_programs_between_runs_unless_told_not_to(tmp_path):
    cache = tmp_path / "cache"
    first = _run_command(
        "example", "--out", str(tmp_path / "a"), env_extra={"BRDFSCALE_COMPILATION_CACHE": str(cache)}, cwd=tmp_path
    )
    assert first.returncode == 0, first.stderr
    assert "Error reading persistent compilation cache" not in first.stderr
    entries = {p.name for p in cache.iterdir()}
    assert entries  # the example's programs were written
    # a second run reads them: nothing new to write
    second = _run_command(
        "example", "--out", str(tmp_path / "b"), env_extra={"BRDFSCALE_COMPILATION_CACHE": str(cache)}, cwd=tmp_path
    )
    assert second.returncode == 0, second.stderr
    assert {p.name for p in cache.iterdir() if not p.name.endswith("-atime")} <= entries
    # switched off: the directory is not even created
    off = tmp_path / "off"
    res = _run_command(
        "--no-compilation-cache",
        "example",
        "--out",
        str(tmp_path / "c"),
        env_extra={"BRDFSCALE_COMPILATION_CACHE": str(off)},
        cwd=tmp_path,
    )
    assert res.returncode == 0, res.stderr
    assert not off.exists()
    # a cache the user configured for JAX wins over the command's own
    own, ours = tmp_path / "own", tmp_path / "ours"
    res = _run_command(
        "example",
        "--out",
        str(tmp_path / "d"),
        env_extra={
            "JAX_COMPILATION_CACHE_DIR": str(own),
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
            "BRDFSCALE_COMPILATION_CACHE": str(ours),
        },
        cwd=tmp_path,
    )
    assert res.returncode == 0, res.stderr
    assert any(own.iterdir()) and not ours.exists()


@pytest.mark.compilation_cache
def test_compilation_cache_directory_and_an_unusable_one(tmp_path, monkeypatch, capsys):
    import jax

    from brdfscale import _compilation_cache as cc

    monkeypatch.delenv("BRDFSCALE_COMPILATION_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cc.cache_directory() == tmp_path / "xdg" / "brdfscale" / "jax"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cc.cache_directory() == tmp_path / "home" / ".cache" / "brdfscale" / "jax"
    # a path below a regular file cannot be a directory: reported, and JAX is left without a cache
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("BRDFSCALE_COMPILATION_CACHE", str(blocker / "cache"))
    assert cc.cache_directory() == blocker / "cache"
    assert jax.config.jax_compilation_cache_dir is None
    assert cc.enable() is None
    assert "compilation cache off" in capsys.readouterr().err
    assert jax.config.jax_compilation_cache_dir is None
