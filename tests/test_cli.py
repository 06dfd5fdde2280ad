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
