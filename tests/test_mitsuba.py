"""brdfscale._mitsuba: the one place that imports Mitsuba 3 and decides its variant."""

import subprocess
import sys
from pathlib import Path

import pytest

import brdfscale
from brdfscale import _mitsuba


pytest.importorskip("mitsuba")


def test_default_variant_runs_and_renders():
    mi = _mitsuba.mitsuba()
    assert mi.variant() in _mitsuba.PREFERRED
    scene = mi.load_dict({"type": "scene", "shape": {"type": "rectangle"}, "emitter": {"type": "constant"}})
    assert scene.bbox().valid()


def test_unknown_variant_is_refused_with_the_list():
    with pytest.raises(brdfscale.InvalidInputError, match="variant must be one of Mitsuba's.*scalar_rgb"):
        _mitsuba.mitsuba("llvm_rgb_typo")


def test_old_llvm_is_refused_before_anything_compiles(tmp_path):
    """With LLVM 15 Mitsuba's LLVM variants abort the process: the check must refuse first, in one line."""
    old = sorted(Path("/usr/lib").glob("*/libLLVM-15.so*"))
    if not old:
        pytest.skip("no LLVM 15 library on this machine to load instead")
    code = (
        "from brdfscale import _mitsuba\n"
        "import brdfscale\n"
        "try:\n    _mitsuba.mitsuba('llvm_ad_rgb')\n"
        "except brdfscale.MissingDependencyError as e:\n    print('REFUSED', e)\n"
        "print('default', _mitsuba.mitsuba().variant())\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code],
        env={"DRJIT_LIBLLVM_PATH": str(old[0]), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert "REFUSED Dr.Jit loaded LLVM 15" in run.stdout and "libllvm19" in run.stdout
    assert "default scalar_rgb" in run.stdout or "default cuda_ad_rgb" in run.stdout


def test_import_selects_no_variant(tmp_path):
    code = "import brdfscale, brdfscale.instrument, brdfscale.render, sys; print('mitsuba' in sys.modules)"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert run.stdout.strip() == "False", run.stderr
