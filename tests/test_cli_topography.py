"""`brdfscale topography FILE --out DIR` and `brdfscale synth --topography FILE` end to end, and the
one parser of `--scales` both share (brdfscale/_cli/_options.py: `scales`, `Scales.resolve`)."""

import argparse
import importlib.util
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import brdfscale._cli as cli
from brdfscale import exr, InvalidInputError, synth, topography
from brdfscale._cli._options import scales


pytest.importorskip("SurfaceTopography")

DATA = Path(__file__).parent / "data" / "topographies"
DI, FRT = str(DATA / "di-3.di"), str(DATA / "frt-1.frt")  # 256² AFM (39.0625 nm pixels); 500² with 30 % unmeasured
PX = 3.90625e-08  # di-3.di's pitch in metres
OUTPUTS = ("statistics.json", "statistics.md", "statistics.png")


@pytest.fixture(autouse=True)
def _only_existing_subcommands(monkeypatch):
    """Register only the subcommand modules that exist (another module may still be missing)."""
    present = tuple(n for n in cli._SUBCOMMANDS if importlib.util.find_spec(f"brdfscale._cli._{n}") is not None)
    monkeypatch.setattr(cli, "_SUBCOMMANDS", present)


@pytest.fixture(scope="module")
def di_field():
    return topography.read(DI)


def doc_mask(path):
    """The measured pixels of an instrument file as read (None: all)."""
    return topography.read(path, detrend=None).mask


def _status(argv) -> int:
    """The exit status of ``brdfscale ARGV``, argparse's usage errors (SystemExit) included."""
    try:
        return cli.main(["--no-compilation-cache", *argv])
    except SystemExit as exit_:
        return exit_.code


def test_outputs_agree_with_facet_statistics(tmp_path, capsys, di_field):
    out = tmp_path / "stats"
    assert _status(["topography", DI, "--scales", "0.625um,1px,4px", "--bins", "65", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == sorted(OUTPUTS)
    doc = json.loads((out / "statistics.json").read_text(encoding="utf-8"))
    direct = synth.facet_statistics(di_field, [PX, 4 * PX, 16 * PX], bins=65)  # the command sorts by μ
    assert [row["mu_px"] for row in doc["scales"]] == [1, 4, 16]
    for row, r in zip(doc["scales"], direct):
        assert row["mu_m"] == r.mu and row["block"] == list(r.block)
        assert (row["count"], row["excluded"]) == (r.count, r.excluded)
        np.testing.assert_allclose(row["covariance"], r.covariance, rtol=1e-12)
        np.testing.assert_allclose(row["covariance_error"], r.covariance_error, rtol=1e-12)
        np.testing.assert_allclose(row["mean"], r.mean, rtol=1e-12, atol=1e-15)
        assert row["independent"] == pytest.approx(r.independent, rel=1e-12)
        assert row["rms_slope"] == pytest.approx(r.rms_slope, rel=1e-12)
    # provenance: the reader's record of the file, the field's geometry, the command
    assert doc["topography"] == json.loads(json.dumps(di_field.description))
    assert doc["topography"]["file"] == "di-3.di" and doc["topography"]["detrend"] == "plane"
    assert doc["field"]["shape"] == [256, 256] and doc["field"]["spacing_m"] == [PX, PX]
    assert doc["field"]["steepest_pixel_slope"] == pytest.approx(synth.steepest_slope(di_field))
    assert doc["command"].startswith(f"brdfscale topography {DI} --detrend plane --scales 0.625um,1px,4px")
    # the table on stdout and in statistics.md: one row per scale, σ = √Σ_aa
    sigma_x = f"{np.sqrt(direct[1].covariance[0, 0]):.4g}"
    assert "σ_x ± err" in printed and sigma_x in printed and "μ (nm)" in printed and " 625 " in printed
    md = (out / "statistics.md").read_text(encoding="utf-8")
    assert md.count("\n| ") == 1 + 3 and sigma_x in md and "Dimension Icon" in md
    assert (out / "statistics.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unmeasured_pixels_are_counted_as_excluded_windows(tmp_path, capsys):
    out = tmp_path / "frt"
    assert (
        _status(["topography", FRT, "--scales", "auto:2", "--bins", "17", "--detrend", "none", "--out", str(out)]) == 0
    )
    doc = json.loads((out / "statistics.json").read_text(encoding="utf-8"))
    # frt-1's heights lie on a lattice (topography.height_quantum): said on stdout and in statistics.md
    quantum = doc["topography"]["height_quantum"]
    expected = topography.height_quantum(topography.read(FRT, detrend=None).heights, doc_mask(FRT))
    assert quantum == pytest.approx(expected, rel=1e-9)
    said = f"heights quantised in steps of {quantum:.4g} m: pixel slopes on a lattice of {quantum / 2.4e-5:.4g} (x)"
    printed, md = capsys.readouterr().out, (out / "statistics.md").read_text(encoding="utf-8")
    assert said in printed and said in md
    # under 1 % of its pixel slopes carry nearly all of their variance (topography.slope_outliers): said too
    outliers = topography.slope_outliers(topography.read(FRT, detrend=None))
    assert doc["field"]["slope_outliers"] == json.loads(json.dumps(outliers.to_json()))
    assert outliers.dominated and outliers.note()[6:] in printed and outliers.note()[6:] in md
    field = doc["field"]
    assert field["unmeasured_pixels"] > 0.2 * 500 * 500 and doc["topography"]["detrend"] is None
    for row in doc["scales"]:
        by, bx = row["block"]
        assert row["excluded"] > 0 and row["count"] + row["excluded"] == (499 // by) * (499 // bx)


def test_refuses_to_overwrite_unless_forced(tmp_path, capsys):
    out = tmp_path / "stats"
    argv = ["topography", DI, "--scales", "8px", "--bins", "17", "--out", str(out)]
    assert _status(argv) == 0
    before = (out / "statistics.json").read_bytes()
    capsys.readouterr()
    assert _status([*argv[:3], "4px", *argv[4:]]) == 2
    err = capsys.readouterr().err
    assert "already holds statistics.png, statistics.md, statistics.json" in err and "--force" in err
    assert (out / "statistics.json").read_bytes() == before
    assert _status([*argv[:3], "4px", *argv[4:], "--force"]) == 0
    assert json.loads((out / "statistics.json").read_text())["scales"][0]["mu_px"] == 4


def test_a_second_run_into_a_directory_in_use_is_refused(tmp_path, capsys):
    out = tmp_path / "busy"
    out.mkdir()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(f"""
        import sys
        from brdfscale import files
        with files.exclusive({str(out)!r}):
            print("held", flush=True)
            sys.stdin.read()
    """),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        assert _status(["topography", DI, "--scales", "8px", "--bins", "17", "--out", str(out)]) == 3
        assert "another run is writing this output directory" in capsys.readouterr().err
        assert not (out / "statistics.json").exists()
    finally:
        holder.communicate("", timeout=30)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--scales", "0.1um"], "--scales 0.1um: 1e-07 m = 2.56 pixels"),
        (["--scales", "300px"], "a scale must be a whole number of pixels along both axes, from 1 to 255"),
        (["--scales", "4"], "a bare number is ambiguous for a field measured in m"),
        (["--scales", "4px,0.15625um"], "4px and 0.15625um are the same scale (4 pixels)"),
        (["--scales", "3furlong"], "argument --scales: unknown unit 'furlong'"),
        (["--scales", "2.5px"], "argument --scales: pixel counts must be whole numbers of pixels"),
        (["--scales=-1um"], "argument --scales: expected 1–64 comma-separated scales"),
        (["--scales", "0um"], "argument --scales: expected 1–64 comma-separated scales"),
        (["--scales", "auto:0"], "auto:COUNT needs a whole COUNT from 1 to 64"),
        (["--channel", "9"], "channel must be an index from 0 to 3 or a name"),
        (["--channel", "Topo"], "has no channel named 'Topo'; its channels are 0: 'ZSensor'"),
        (["--detrend", "cubic"], "argument --detrend: invalid choice"),
        (["--bins", "1"], "argument --bins: must be an integer in [2, 4097]"),
    ],
)
def test_bad_options_exit_2_with_one_line(tmp_path, capsys, extra, message):
    out = tmp_path / "o"
    assert _status(["topography", DI, *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_bad_files_and_a_missing_extra_exit_2(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o"
    (tmp_path / "notes.txt").write_text("not a height map\n")
    for path, message in (
        (tmp_path / "absent.di", "absent.di: does not exist"),
        (tmp_path / "notes.txt", "cannot read it as a topography"),
        (tmp_path, "is a directory"),
    ):
        assert _status(["topography", str(path), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and "Traceback" not in err
    (tmp_path / "file").write_text("")
    assert _status(["topography", DI, "--out", str(tmp_path / "file")]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "SurfaceTopography", None)  # as if the extra were not installed
    assert _status(["topography", DI, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert 'pip install "brdfscale[topography]"' in err and err.count("\n") == 1
    assert not out.exists()


def test_scales_parser_resolves_units_pixels_and_auto(di_field):
    same = [
        scales(t).resolve(di_field)
        for t in ("4px", "0.15625um", "0.15625µm", "0.15625\u03bcm", "1.5625e-7m", "156.25nm", "1.5625e-4mm", "1562.5A")
    ]
    assert all(s == [4 * PX] for s in same)
    assert scales("auto:3").resolve(di_field) == di_field.scales(3)
    assert scales("auto").resolve(di_field) == di_field.scales(8)
    assert scales("1px, 2px,,").resolve(di_field) == [PX, 2 * PX]
    assert scales("4,16").pixels() == [4.0, 16.0] and scales("4um").pixels() is None
    square = synth.named_surface("gaussian", size=32, seed=0)  # a built-in surface: lengths in pixels, no unit
    assert scales("4,8px").resolve(square) == [4.0, 8.0]
    with pytest.raises(InvalidInputError, match="this surface's lengths are in pixels"):
        scales("1um").resolve(square)
    with pytest.raises(argparse.ArgumentTypeError, match="expected 1–64"):
        scales(",".join(["1px"] * 65))


def test_synth_from_a_topography_writes_a_measurement_set(tmp_path, capsys, di_field):
    out = tmp_path / "di.exr"
    argv = [
        "synth",
        "--topography",
        DI,
        "--scales",
        "2px,0.3125um",
        "--incident",
        "0",
        "--incident",
        "20:90",
        "--pixels",
        "17",
        "--noise",
        "poisson:1000",
        "--seed",
        "5",
        "--out",
        str(out),
    ]
    assert _status(argv) == 0
    assert "4 lobe images (di-3.di, 256 × 256 measured field" in capsys.readouterr().out
    mset = exr.read_measurements(out)
    assert len(mset.images) == 2 * 2 and sorted({p.mu for p in mset.images}) == [2 * PX, 8 * PX]
    meta = mset.metadata
    assert meta["surface"] == json.loads(json.dumps(di_field.description))  # the topography's provenance
    assert meta["command"] == f"brdfscale synth --topography {DI} --detrend plane --scales 2px,0.3125um"
    assert meta["unit"] == "m" and meta["periodic"] is False and meta["seed"] == 5
    assert meta["extent"] == pytest.approx(synth.robust_extent(di_field))  # robust quantiles, not the steepest pixel
    assert mset.images[0].sigma is not None
    again = tmp_path / "again.exr"  # the same seed, the same noise
    assert _status([*argv[:-1], str(again)]) == 0
    assert all(np.array_equal(a.values, b.values) for a, b in zip(exr.read_measurements(again).images, mset.images))
    assert _status(["info", str(out)]) == 0
    assert "surface: di-3.di (measured, Dimension Icon, detrend plane)" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["synth", "gaussian", "--topography", DI], "give either a built-in SURFACE or --topography FILE"),
        (["synth"], "give either a built-in SURFACE or --topography FILE"),
        (["synth", "--topography", DI, "--size", "64"], "--size sets the size of a built-in SURFACE"),
        (["synth", "--topography", DI, "--seed", "3", "--noise", "none"], "the seed only seeds the noise"),
        (
            ["synth", "gaussian", "--channel", "0", "--detrend", "none"],
            "--channel and --detrend: how a topography file is read",
        ),
        (["synth", "gaussian", "--scales", "4um"], "this surface's lengths are in pixels"),
        (["synth", "--topography", DI, "--scales", "4,16"], "a bare number is ambiguous"),
        (["synth", "--topography", str(DATA / "missing.mi")], "missing.mi: does not exist"),
    ],
)
def test_synth_refuses_options_that_do_not_apply(tmp_path, capsys, argv, message):
    out = tmp_path / "x.exr"
    assert _status([*argv, "--pixels", "9", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.slow  # ≈ 8 s on 2 cores (the fit's first compilation)
def test_fit_runs_on_a_topography_measurement_set(tmp_path, capsys):
    data = tmp_path / "di.exr"
    assert (
        _status(
            [
                "synth",
                "--topography",
                DI,
                "--scales",
                "2px,8px,32px",
                "--pixels",
                "33",
                "--noise",
                "poisson:1000",
                "--out",
                str(data),
            ]
        )
        == 0
    )
    argv = ["fit", str(data), "--out", str(tmp_path / "fit"), "--model", "parametric", "--steps", "0"]
    status = _status([*argv, "--starts", "2"])
    doc = json.loads((tmp_path / "fit" / "fit.json").read_text())
    # the exit status is the report's verdict (docs/fitting.md): di-3's lobes are not Beckmann, so 5 with the report
    assert (status, doc["outcome"]["status"]) in ((0, "ok"), (5, "inadequate"))
    assert doc["optimisation"]["reduced_chi2"] > 0 and "alpha_lobe" in doc["parameters"]


def test_readmes_measured_surface_commands_name_a_file_and_options_that_exist(di_field):
    """README's measured-surface block, as a new user copies it from the root of a clone: the file it
    names exists, every ``brdfscale`` line parses, and the ``--scales`` README gives as an example are
    whole numbers of pixels of that file (a walk-through found ``di-3.di`` without its folder, and
    ``--scales 1um,4um``, 25.6 pixels of di-3, refused)."""
    import shlex

    root = Path(__file__).resolve().parents[1]  # the block runs from the root of a clone
    readme = (root / "README.md").read_text(encoding="utf-8")
    block = next(b for b in (c.split("```")[0] for c in readme.split("```bash")[1:]) if "synth --topography" in b)
    lines = [line.split("#")[0].strip() for line in block.splitlines()]
    variables = dict(line.split("=", 1) for line in lines if "=" in line and " " not in line)
    assert list(variables) == ["FILE"] and (root / variables["FILE"]).resolve() == Path(DI).resolve()
    commands = [shlex.split(line.replace("$FILE", DI)) for line in lines if line.startswith("brdfscale")]
    assert [c[1] for c in commands] == ["topography", "synth", "fit"]
    parser = cli.build_parser()
    for argv in commands:
        assert parser.parse_args(argv[1:]).func
    example = readme.split("`--scales ")[1].split("`")[0]
    assert scales(example).resolve(di_field) == [16 * PX, 64 * PX]
