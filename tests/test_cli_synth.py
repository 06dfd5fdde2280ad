"""`brdfscale synth` and `brdfscale info` end to end."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

import brdfscale._cli as cli
from brdfscale import exr


@pytest.fixture(autouse=True)
def _only_existing_subcommands(monkeypatch):
    """Register only the subcommand modules that exist (another module may still be missing)."""
    present = tuple(n for n in cli._SUBCOMMANDS if importlib.util.find_spec(f"brdfscale._cli._{n}") is not None)
    monkeypatch.setattr(cli, "_SUBCOMMANDS", present)


def test_synth_then_info(tmp_path, capsys):
    out = tmp_path / "set.exr"
    argv = [
        "synth",
        "blazed",
        "--out",
        str(out),
        "--size",
        "160",
        "--scales",
        "1,16,32",
        "--incident",
        "0",
        "--incident",
        "30:90",
        "--noise",
        "poisson:1000",
        "--seed",
        "4",
        "--pixels",
        "17",
    ]
    assert cli.main(argv) == 0
    mset = exr.read_measurements(out)
    assert len(mset.images) == 6 and sorted(set(p.mu for p in mset.images)) == [1.0, 16.0, 32.0]
    np.testing.assert_allclose(mset.images[1].incident, [0.0, 0.5, np.sqrt(0.75)], atol=1e-15)
    assert mset.metadata["seed"] == 4 and mset.metadata["noise"] == {
        "type": "poisson",
        "exposure": 1000.0,
        "read_noise": 0.0,
    }
    assert mset.images[0].sigma is not None
    capsys.readouterr()
    assert cli.main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "measurement_set, 6 parts" in text and "surface: blazed" in text and "(30, 90)" in text
    assert cli.main(["info", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["parts"] == 6 and summary["scales"] == [1.0, 16.0, 32.0]
    # the same seed gives the same file contents
    again = tmp_path / "again.exr"
    assert cli.main([*argv[:2], "--out", str(again), *argv[4:]]) == 0
    for a, b in zip(exr.read_measurements(again).images, mset.images):
        assert np.array_equal(a.values, b.values)


def test_no_overwrite_without_force(tmp_path, capsys):
    out = tmp_path / "set.exr"
    base = ["synth", "gaussian", "--out", str(out), "--size", "64", "--scales", "4,16", "--pixels", "9"]
    assert cli.main(base) == 0
    before = out.read_bytes()
    assert cli.main(base + ["--seed", "2"]) == 2
    assert "file exists" in capsys.readouterr().err and out.read_bytes() == before
    assert cli.main(base + ["--seed", "2", "--force"]) == 0
    assert out.read_bytes() != before


def test_a_lobe_cut_by_the_default_extent_is_one_warning_line(tmp_path, capsys):
    """Rough micro facets (--micro-alpha) and the default extent (the pixel slopes'): the images cut the lobe, and
    the command says so in one line on stderr (brdfscale.LobeCutWarning through the command's warning format, not
    Python's file:line and source line), then writes the file; Python's warning settings are as before."""
    import warnings

    out = tmp_path / "rough.exr"
    before = warnings.showwarning
    argv = ["synth", "gaussian", "--out", str(out), "--size", "64", "--scales", "4,16", "--pixels", "9"]
    assert cli.main([*argv, "--micro-alpha", "0.5"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("brdfscale synth: warning: the image at μ = "), err
    assert "of its lobe's light" in err[0] and "--extent" in err[0] and out.exists()
    assert warnings.showwarning is before


def test_info_on_lobe_table_and_on_a_bad_file(tmp_path, capsys):
    table = exr.LobeTable([1.0, 2.0], 0.1, np.ones((2, 5, 5)))
    path = tmp_path / "t.exr"
    exr.write_lobe_table(path, table)
    assert cli.main(["info", str(path)]) == 0
    assert "lobe_table, 2 parts" in capsys.readouterr().out
    junk = tmp_path / "junk.exr"
    junk.write_text("x")
    assert cli.main(["info", str(junk)]) == 2
    assert "not a readable OpenEXR" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv",
    [
        ["synth", "velvet", "--out", "x.exr"],
        ["synth", "gaussian", "--out", "x.exr", "--incident", "95"],
        ["synth", "gaussian", "--out", "x.exr", "--noise", "poisson:-1"],
        ["synth", "gaussian", "--out", "x.exr", "--scales", "a,b"],
        ["synth", "gaussian", "--out", "x.exr", "--micro-alpha", "x"],
    ],
)
def test_bad_arguments_exit_with_usage_error(argv, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    assert not (tmp_path / "x.exr").exists()


def test_rough_micro_facets(tmp_path):
    out = tmp_path / "rough.exr"
    assert (
        cli.main(
            [
                "synth",
                "gaussian",
                "--out",
                str(out),
                "--size",
                "64",
                "--scales",
                "64",
                "--micro-alpha",
                "0.02",
                "--pixels",
                "33",
                "--extent",
                "0.1",
            ]
        )
        == 0
    )
    mset = exr.read_measurements(out)
    assert mset.metadata["micro"]["type"] == "Gaussian"
    image = mset.images[0]
    h = 0.2 / 32
    assert image.values.sum() * h * h == pytest.approx(1.0, abs=1e-3)  # the blurred lobe stays inside the grid


def test_library_errors_exit_2(tmp_path, capsys):
    # a fractional scale is refused while parsing (the domain --help states), a library error after it
    with pytest.raises(SystemExit) as info:
        cli.main(["synth", "gaussian", "--out", str(tmp_path / "x.exr"), "--size", "64", "--scales", "3.5"])
    assert info.value.code == 2 and "whole numbers of pixels" in capsys.readouterr().err
    (tmp_path / "x.exr").write_bytes(b"not an exr")
    assert cli.main(["info", str(tmp_path / "x.exr")]) == 2
    assert "not a readable OpenEXR file" in capsys.readouterr().err


DI = str(Path(__file__).parent / "data" / "topographies" / "di-3.di")


def test_synth_help_states_the_topography_defaults(capsys):
    from brdfscale._cli._synth import TOPOGRAPHY_NOISE, TOPOGRAPHY_RESOLUTION

    with pytest.raises(SystemExit):
        cli.main(["synth", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"{TOPOGRAPHY_NOISE} for --topography" in text
    assert f"{TOPOGRAPHY_RESOLUTION:g} image pixels" in text
    assert "99th percentile of the pixel slopes' deviation |m − m̄|" in text and "steepest" not in text


def test_synth_topography_records_only_the_defaults_it_used(tmp_path):
    """Options given are not defaults: --noise none, --extent and --resolution leave `defaults` empty
    and the images without σ; --noise given but no --extent records the extent rule alone."""
    from brdfscale import synth, topography

    out = tmp_path / "given.exr"
    given = ["--noise", "none", "--extent", "0.5", "--resolution", "0", "--pixels", "17", "--scales", "auto:2"]
    assert cli.main(["synth", "--topography", DI, *given, "--out", str(out)]) == 0
    mset = exr.read_measurements(str(out))
    assert mset.metadata["defaults"] == {} and all(image.sigma is None for image in mset.images)
    assert mset.metadata["extent"] == 0.5 and mset.metadata["resolution"] == 0.0
    out = tmp_path / "extent.exr"
    args = ["--noise", "gaussian:0.1", "--seed", "4", "--pixels", "17", "--scales", "auto:2"]
    assert cli.main(["synth", "--topography", DI, *args, "--out", str(out)]) == 0
    mset = exr.read_measurements(str(out))
    assert set(mset.metadata["defaults"]) == {"extent", "resolution"}
    assert mset.metadata["extent"] == pytest.approx(synth.robust_extent(topography.read(DI)))
    assert mset.metadata["noise"]["type"] == "gaussian" and all(image.sigma is not None for image in mset.images)
    # the field's slope outliers, for fit's ΔΣ-truth table (what carries the surface's Σ)
    outliers = topography.slope_outliers(topography.read(DI)).to_json()
    assert mset.metadata["truth"]["slope_outliers"] == json.loads(json.dumps(outliers))
