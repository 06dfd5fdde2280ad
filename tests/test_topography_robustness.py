"""Damaged instrument files, hostile heights and pixels that are not square (issues 34 and 31).

References nobody here wrote: the instrument files of tests/data/topographies and what
SurfaceTopography decodes from their damaged copies; closed forms — a quadratic surface (which
cubic convolution reproduces exactly), the O(Δ³) convergence of Keys' interpolation on a smooth
analytic surface, and the exact facet-slope covariance of a random-phase sum of plane waves
averaged over a rectangular window (Dirichlet sums, written below).
"""

import io
import json
import math
import types
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, HealthCheck, settings, strategies as hs

from brdfscale import _cli as cli, InvalidInputError, MeasurementFileError, plot, synth, topography


st_module = pytest.importorskip("SurfaceTopography")

from tests.references import topography_mutation as mutation  # noqa: E402 — needs SurfaceTopography


DATA = Path(__file__).parent / "data" / "topographies"
MNT = DATA / "mnt-1.mnt"  # MountainsMap: 960 × 600 pixels of 1.85339 × 1.85455 µm
X3P_PITCH = (1.27656509837346e-07, 3.14582113527746e-07)  # the X3P file of issue 31: 127.7 × 314.6 nm


def _main(argv, capsys) -> tuple[int, str, str]:
    try:
        code = cli.main(["--no-compilation-cache", *argv])
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def references():
    return {name: topography.read(str(DATA / name), detrend=None) for name in mutation.FILES}


# -- damaged files -----------------------------------------------------------------------------------


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=hs.sampled_from(mutation.FILES), kind=hs.sampled_from(mutation.BYTE_KINDS), seed=hs.integers(0, 2**32 - 1))
def test_a_damaged_instrument_file_gives_the_librarys_error_or_what_it_holds(tmp_path, references, name, kind, seed):
    """Any byte mutation: MeasurementFileError naming the file in one line, the undamaged field, or
    exactly what SurfaceTopography decodes from the damaged file with finite Σ(μ) (a byte of
    heights hit is a different measurement: the formats carry no checksum); nothing printed."""
    path = tmp_path / f"mutant{Path(name).suffix}"
    path.write_bytes(mutation.mutate((DATA / name).read_bytes(), kind, np.random.default_rng(seed)))
    verdict, why = mutation.read_outcome(str(path), references[name])
    assert verdict in ("refused", "same", "faithful"), why


def test_truncated_files_are_refused_naming_the_file(tmp_path):
    """A .di cut inside its header (IndexError from default_channel before), and each format cut short."""
    for name, keep in (
        ("di-3.di", 1581),
        ("di-3.di", 3998),
        ("mi-1.mi", 2000),
        ("opd-1.opd", 900),
        ("mnt-1.mnt", 5000),
    ):
        path = tmp_path / name
        path.write_bytes((DATA / name).read_bytes()[:keep])
        with pytest.raises(MeasurementFileError, match=f"^{path}: ") as err:
            topography.read(path)
        assert "\n" not in str(err.value)


class _Channel:  # what brdfscale reads of SurfaceTopography's ChannelInfo
    name, dim, nb_grid_pts, physical_sizes = "Z", 2, (8, 8), (8.0, 8.0)


@pytest.mark.parametrize(
    "where, error",
    [
        ("open", KeyError("ScanSize")),
        ("channels", ValueError("could not convert string to float: 'x'")),
        ("default_channel", IndexError("list index out of range")),
        ("topography", OverflowError("cannot convert float infinity to integer")),
        ("heights", MemoryError()),
    ],
)
def test_every_failure_inside_surface_topography_is_a_measurement_file_error(tmp_path, monkeypatch, where, error):
    """The one boundary: whatever SurfaceTopography raises — at open, in ``reader.channels``
    (outside the try before), in ``default_channel``, ``topography()`` or ``heights()`` —
    becomes MeasurementFileError naming the file and the exception."""
    path = tmp_path / "scan.di"
    path.write_bytes(b"not really")

    def fail(*_, **__):
        raise error

    class Topo:
        dim, unit, info = 2, "nm", {}
        nb_grid_pts, physical_sizes = (8, 8), (8.0, 8.0)
        heights = fail if where == "heights" else staticmethod(lambda: np.zeros((8, 8)))

    class Reader:
        channels = property(fail) if where == "channels" else [_Channel()]
        default_channel = property(fail) if where == "default_channel" else None
        topography = fail if where == "topography" else staticmethod(lambda channel_index=0: Topo())

    monkeypatch.setattr(st_module, "open_topography", fail if where == "open" else lambda _: Reader())
    with pytest.raises(MeasurementFileError, match=f"^{path}: SurfaceTopography .*{type(error).__name__}"):
        topography.read(path)


def test_a_date_the_reader_cannot_parse_is_a_measurement_file_error(tmp_path):
    """dateutil's ParserError on a damaged acquisition date in the .opd header."""
    data = bytearray((DATA / "opd-1.opd").read_bytes())
    date = data.find(b"Date")
    assert date > 0
    value = date + 16  # the field's value follows its 16-byte name in the header block
    data[value : value + 8] = b":19:487/"
    path = tmp_path / "opd-1.opd"
    path.write_bytes(bytes(data))
    try:
        field = topography.read(path, detrend=None)
    except MeasurementFileError as err:
        assert str(err).startswith(f"{path}: ")
    else:  # the bytes were not the date after all: then the field is what the file holds
        assert mutation.faithful(str(path), field)


def test_reader_logging_stays_off_the_terminal(tmp_path, capfd):
    """igor2 logs a 100 kB dump of a damaged header while SurfaceTopography tries its reader on
    a .plu; a read prints nothing, and the refusal is one line."""
    data = bytearray((DATA / "plu-1.plu").read_bytes())
    data[1000:1000] = bytes(range(1, 9))
    path = tmp_path / "plu-1.plu"
    path.write_bytes(bytes(data))
    try:
        topography.read(path)
    except MeasurementFileError as err:
        assert "\n" not in str(err)
    out, err = capfd.readouterr()
    assert out == "" and "could not reshape" not in err


def test_a_readers_python_warning_joins_the_reason_of_a_file_it_cannot_read(tmp_path, monkeypatch, recwarn):
    """openpyxl warns (Python's warnings) about an image inside SurfaceTopography's own ``mitutoyo_2_mock.xlsx``
    while reading it, which put a second line before the refusal (experiments/corpus_chain.py met it): what a
    reader warns joins the reason of a file that cannot be read (its first line) instead of printing before it."""
    path = tmp_path / "scan.di"
    path.write_bytes(b"not really")

    def warn_then_fail(_):
        import warnings

        warnings.warn("wmf image format is not supported so the image is being dropped", UserWarning, stacklevel=1)
        raise KeyError("ScanSize")

    monkeypatch.setattr(st_module, "open_topography", warn_then_fail)
    with pytest.raises(MeasurementFileError, match=r"KeyError.*it logged: wmf image format is not supported"):
        topography.read(path)
    assert not any("wmf" in str(w.message) for w in recwarn)


def _reader_that_warns(monkeypatch):
    """SurfaceTopography's reader, patched to warn as openpyxl does (mitutoyo_2_mock.xlsx) before it reads."""
    real = st_module.open_topography

    def warn_then_read(name):
        import warnings

        warnings.warn("wmf image format is not supported so the image is being dropped", UserWarning, stacklevel=1)
        return real(name)

    monkeypatch.setattr(st_module, "open_topography", warn_then_read)


def test_a_readers_python_warning_on_a_file_it_reads_is_the_callers_again(tmp_path, monkeypatch, capsys):
    """The same warning from a reader that then reads the file (nc-1.nc) is shown once the file is read and its
    heights accepted — as the reader issued it (its category; the caller's filters applied when it did), not
    swallowed; the command prints it as one line of its own."""
    _reader_that_warns(monkeypatch)
    with pytest.warns(UserWarning, match="wmf image format is not supported"):
        field = topography.read(str(DATA / "nc-1.nc"))
    assert field.shape == (10, 5)
    code, _, err = _main(["topography", str(DATA / "nc-1.nc"), "--out", str(tmp_path / "t")], capsys)
    warned = [line for line in err.splitlines() if "wmf" in line]
    assert code == 0 and warned == [
        "brdfscale topography: warning: wmf image format is not supported so the image is being dropped"
    ], err


def test_a_readers_warning_on_a_file_whose_heights_are_refused_is_not_shown(tmp_path, monkeypatch, capsys, recwarn):
    """A reader that warns and hands over a 3 × 3 map: the refusal (too small, from_array's) is the one line the
    command prints — the warning is shown only for a file that is read and accepted."""
    path = _text_file(tmp_path / "tiny.txt", np.arange(9.0).reshape(3, 3) * 1e-8)
    _reader_that_warns(monkeypatch)
    with pytest.raises(MeasurementFileError, match="at least 4 × 4 pixels"):
        topography.read(path)
    assert not any("wmf" in str(w.message) for w in recwarn)
    code, _, err = _main(["topography", path, "--out", str(tmp_path / "t")], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "wmf" not in err, err


# -- absurd pitches and heights ----------------------------------------------------------------------


def test_absurd_pitches_are_refused_with_the_reason():
    h = np.random.default_rng(0).standard_normal((8, 8)) * 1e-8
    for spacing, message in (
        (1e-300, "outside the physical range"),
        (1e300, "outside the physical range"),
        ((1e-7, 1e3), "differ by more than a factor"),
    ):
        with pytest.raises(InvalidInputError, match=message):
            topography.from_array(h, spacing)
    with pytest.raises(InvalidInputError, match="differ by more than a factor"):
        synth.HeightField(h, (1e-300, 1e10), periodic=False)  # HeightField.scales overflowed (OverflowError)


@pytest.mark.parametrize(
    "factor, message",
    [(1e300, "above 1e\\+06"), (1e150, "above 1e\\+06"), (1e-302, "below 1e-30")],
)
def test_huge_and_denormal_heights_are_refused_naming_the_steepest_slope(factor, message):
    h = np.random.default_rng(1).standard_normal((16, 16)) * 1e-8 * factor
    with pytest.raises(InvalidInputError, match=f"steepest pixel slope is .*{message}"):
        topography.from_array(h, 1e-7)
    with pytest.raises(InvalidInputError, match=message):
        synth.HeightField(h / 1e-7, 1.0)


def test_a_flat_surface_is_measured_exactly_flat():
    """A constant map detrends to exactly 0 (the plane is fitted relative to one measured
    height), so Σ(μ) = 0 at every scale and the lobes are in one node."""
    for mode in ("plane", "curvature", None):
        field = topography.from_array(np.full((12, 20), 3.7e-7), (1e-7, 1e-7), detrend=mode)
        assert field.steepest_slope == 0 and np.all(field.heights == (3.7e-7 if mode is None else 0.0))
        stats = synth.facet_statistics(field, field.scales(3), bins=9)
        assert all(np.all(s.covariance == 0) and np.all(s.covariance_error == 0) for s in stats)
    buffer = io.BytesIO()
    plot.facet_statistics(stats, field=field).savefig(buffer, format="png")
    assert buffer.tell() > 0


def test_nan_patches_are_unmeasured_pixels():
    h = np.random.default_rng(2).standard_normal((20, 20)) * 1e-8
    h[3:5, 7:10] = np.nan
    field = topography.from_array(h, 1e-7)
    explicit = topography.from_array(np.nan_to_num(h), 1e-7, mask=~np.isnan(h))
    assert mutation.same_field(field, explicit) and int((~field.mask).sum()) == 6


def _text_file(path: Path, heights: np.ndarray, pitch: float = 1e-7) -> str:
    mutation.write_ascii(str(path), heights, pitch, pitch)
    return str(path)


def test_the_command_measures_a_flat_surface_and_draws_its_figure(tmp_path, capsys):
    path = _text_file(tmp_path / "flat.txt", np.full((24, 24), 2e-6))
    code, out, err = _main(["topography", path, "--out", str(tmp_path / "out")], capsys)
    assert code == 0, err
    assert "note: the surface is flat (every measured pixel slope is 0)" in out
    doc = json.loads((tmp_path / "out" / "statistics.json").read_text())
    assert doc["field"]["flat"] is True and doc["lobe_extent"] is None
    assert all(np.all(np.array(s["covariance"]) == 0) for s in doc["scales"])
    assert (tmp_path / "out" / "statistics.png").stat().st_size > 0


@pytest.mark.parametrize("factor, reason", [(1e-302, "below 1e-30"), (1e300, "above 1e+06"), (1e150, "above 1e+06")])
def test_the_command_refuses_denormal_and_huge_heights_in_one_line(tmp_path, capsys, factor, reason):
    heights = np.random.default_rng(3).standard_normal((24, 24)) * 1e-8 * factor
    path = _text_file(tmp_path / "hostile.txt", heights)
    code, out, err = _main(["topography", path, "--out", str(tmp_path / "out")], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"brdfscale topography: error: {path}: ") and reason in lines[0]
    assert not (tmp_path / "out" / "statistics.json").exists()


def test_a_file_without_a_height_unit_is_refused_naming_the_way_round(tmp_path, capsys):
    """SurfaceTopography's own test file ``10x10-one_channel_without_name.ibw`` (Asylum Igor; a 10 × 10 map whose
    heights carry no unit, tests/data/topographies/README.md): ``read`` refuses it as a MeasurementFileError that
    says the file records no unit and names ``from_array``, the way to give the unit; the commands end with exit
    2 and that one line (experiments/corpus_chain.py met it)."""
    path = str(DATA / "10x10-one_channel_without_name.ibw")
    with pytest.raises(MeasurementFileError, match=r"records no unit for its heights.*topography\.from_array"):
        topography.read(path)
    for command in (
        ["topography", path, "--out", str(tmp_path / "t")],
        ["synth", "--topography", path, "--out", str(tmp_path / "m.exr")],
    ):
        code, _, err = _main(command, capsys)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
        assert "records no unit for its heights" in lines[0] and "from_array(heights, spacing, unit=...)" in lines[0]


def test_a_file_of_an_exact_plane_is_a_flat_field_and_synth_refuses_it_in_one_line(tmp_path, capsys):
    """SurfaceTopography's own ``nc-1.nc`` (tests/data/topographies/README.md): 10 × 5 pixels of 1 nm whose heights
    are an exact plane, steps of 2 nm. Detrended, it is a flat field — every height exactly 0, no slope quantum
    (the tilt's 2 nm step is no lattice of its slopes) — so ``topography`` says the surface is flat and
    ``synth --topography`` refuses it with exit 2 and one line. Before, the plane's rounding (rms slope 2e-15)
    passed for a texture and the tilt's step for a slope quantum of 2, and synth asked for a 9e16² image grid
    (experiments/corpus_chain.py met it)."""
    path = str(DATA / "nc-1.nc")
    field = topography.read(path)
    assert field.shape == (10, 5) and not np.any(field.heights) and field.description["height_quantum"] is None
    code, out, err = _main(["topography", path, "--out", str(tmp_path / "t")], capsys)
    assert code == 0 and "the surface is flat" in out + err, (out, err)
    code, _, err = _main(["synth", "--topography", path, "--out", str(tmp_path / "m.exr")], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].endswith("a spike at one slope, no lobe to image.") and not (tmp_path / "m.exr").exists()


def test_a_file_without_a_pitch_is_refused_naming_the_way_round(tmp_path, capsys):
    """A NumPy ``.npy`` height map (SurfaceTopography reads its heights but no physical size; its own
    ``example-2d.npy`` and ``matrix-5.txt`` are such files): refused before SurfaceTopography's "physical_sizes could
    not be extracted", as a MeasurementFileError that says the pitch is missing and names ``from_array`` — not the
    reader's "check the file is an undamaged instrument height map" (experiments/corpus_chain.py met it)."""
    path = tmp_path / "heights.npy"
    np.save(path, np.random.default_rng(0).standard_normal((16, 16)))
    with pytest.raises(MeasurementFileError, match=r"not their pitch.*topography\.from_array") as caught:
        topography.read(str(path))
    assert "undamaged" not in str(caught.value)
    code, _, err = _main(["topography", str(path), "--out", str(tmp_path / "t")], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "not their pitch" in err, err


def test_an_empty_file_holds_no_heights(tmp_path):
    """An empty ``.txt`` (SurfaceTopography's HGT reader takes it as a 0 × 0 map without a physical size): refused
    as holding no heights — not as a map without a pitch."""
    path = tmp_path / "empty.txt"
    path.write_bytes(b"")
    with pytest.raises(MeasurementFileError, match=r"holds no heights \(0 × 0 pixels") as caught:
        topography.read(str(path))
    assert "pitch" not in str(caught.value)


def test_a_channel_that_is_not_heights_is_refused_naming_the_height_channels(tmp_path, capsys):
    """di-3.di's channel 1 is the AFM's amplitude error (SurfaceTopography gives its unit as ('µm', None)): refused
    naming what it holds and the file's other channels, with the argument that chooses one (``channel=``, which the
    command writes ``--channel``) — not from_array, and not channel 2, the phase, whose unit is ('µm', None) too."""
    with pytest.raises(
        MeasurementFileError, match=r"channel 1 \('AmplitudeError'\) holds .*channel= among .*3: 'Height'"
    ) as e:
        topography.read(str(DATA / "di-3.di"), channel=1)
    assert "from_array" not in str(e.value) and "'Phase'" not in str(e.value) and "0: 'ZSensor'" in str(e.value)
    code, _, err = _main(["topography", str(DATA / "di-3.di"), "--channel", "1", "--out", str(tmp_path / "t")], capsys)
    assert code == 2 and "reads as heights with --channel among" in err and "channel=" not in err, err


class _Info:  # SurfaceTopography ≥ 1.27's ChannelInfo, as an Asylum .ibw's: the lateral unit on every channel
    dim, nb_grid_pts, physical_sizes, unit = 2, (8, 8), (8e-6, 8e-6), "m"

    def __init__(self, name, kind, data_unit, is_height_channel):
        self.name, self.data_unit, self.is_height_channel = name, data_unit, is_height_channel
        self.data_kind = types.SimpleNamespace(value=kind)


def test_a_channel_of_phase_or_volts_is_refused_from_its_data_unit_naming_the_height_channels(tmp_path, monkeypatch):
    """The channels of SurfaceTopography's own spot_1-1000nm.ibw (Asylum; SurfaceTopography 1.27.1's channel
    information, every ``unit`` the lateral 'm'): its phase (data unit 'deg', not a height channel) is refused
    before its values are read as metres, saying what it holds, and the line names the channels SurfaceTopography
    reads as heights — the two height channels and, by its judgement (a length unit), the two amplitudes; not the
    phases or the potentials."""
    path = tmp_path / "scan.ibw"
    path.write_bytes(b"not read")
    channels = [
        _Info("HeightTrace", "height", "m", True),
        _Info("HeightRetrace", "height", "m", True),
        _Info("AmplitudeTrace", "height", "m", True),
        _Info("AmplitudeRetrace", "height", "m", True),
        _Info("PhaseTrace", "phase", "deg", False),
        _Info("PhaseRetrace", "phase", "deg", False),
        _Info("NapPotentialTrace", "voltage", "V", False),
        _Info("NapPotentialRetrace", "voltage", "V", False),
    ]

    class Reader:
        default_channel = channels[0]

        def __init__(self):
            self.channels = channels

        def topography(self, channel_index=0):
            raise AssertionError("a channel that is not heights is not read")

    monkeypatch.setattr(st_module, "open_topography", lambda _: Reader())
    with pytest.raises(MeasurementFileError, match=r"channel 4 \('PhaseTrace'\) holds phase data \('deg'\), not") as e:
        topography.read(str(path), channel=4)
    assert str(e.value).endswith(
        "with channel= among 0: 'HeightTrace', 1: 'HeightRetrace', 2: 'AmplitudeTrace', 3: 'AmplitudeRetrace'."
    )


def test_synth_refuses_a_default_that_gives_one_scale(tmp_path, capsys):
    """A 4 × 7 height map (SurfaceTopography's own ``sdf-1.sdf`` is one): ``--scales auto:8`` admits a single facet
    scale, and ``fit`` needs two — ``synth --topography`` refuses in one line naming the default and the way round
    (it wrote a one-scale set that ``fit`` then refused, experiments/corpus_chain.py met it); the scales given by
    name, and one automatic scale asked for (``auto:1``), are made."""
    path = _text_file(tmp_path / "small.txt", np.random.default_rng(5).standard_normal((4, 7)) * 1e-8)
    code, _, err = _main(["synth", "--topography", path, "--out", str(tmp_path / "m.exr")], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "admits 1 facet scale (μ = " in lines[0], err
    assert "(the default)" in lines[0] and "1px,2px" in lines[0] and not (tmp_path / "m.exr").exists()
    code, _, err = _main(
        ["synth", "--topography", path, "--scales", "1px,2px", "--out", str(tmp_path / "m.exr")], capsys
    )
    assert code == 0, err
    code, _, err = _main(
        ["synth", "--topography", path, "--scales", "auto:1", "--out", str(tmp_path / "a.exr")], capsys
    )
    assert code == 0, err  # one scale asked for is made, as by name


# -- nearly square pixels ------------------------------------------------------------------------------


def test_pitches_equal_to_the_tolerance_are_made_square_and_the_difference_recorded():
    dx, dy = 1.853393117831074e-06, 1.8545542570951588e-06  # the MountainsMap file's pitches
    h = np.random.default_rng(4).standard_normal((30, 40)) * 1e-8
    field = topography.from_array(h, (dx, dy))
    d = math.sqrt(dx * dy)
    assert field.spacing == (pytest.approx(d, rel=1e-15), pytest.approx(d, rel=1e-15))
    record = field.description["square_pixels"]
    assert record["pitch_as_given"] == [dx, dy] and record["relative_difference"] == pytest.approx((dy - dx) / dy)
    assert record["tolerance"] == synth.HeightField.LENGTH_TOLERANCE == 1e-3
    wider = topography.from_array(h, (dx, dx * 1.0011))  # 0.11 %: rectangular, kept as given
    assert wider.spacing == (dx, dx * 1.0011) and "square_pixels" not in wider.description


def test_the_mountainsmap_file_is_read_square_and_measured():
    field = topography.read(MNT)
    (dx, dy), record = field.spacing, field.description["square_pixels"]
    assert dx == dy and record["relative_difference"] == pytest.approx(6.26e-4, rel=1e-3)
    stats = synth.facet_statistics(field, [dx, 4 * dx], bins=9)
    assert [s.block for s in stats] == [(1, 1), (4, 4)]
    assert all(np.all(np.isfinite(s.covariance)) and s.covariance[0, 0] > 0 for s in stats)


def test_the_command_prints_and_records_pixels_made_square(tmp_path, capsys):
    dx, dy = 1.853393117831074e-06, 1.8545542570951588e-06
    heights = np.random.default_rng(7).standard_normal((24, 32)) * 1e-8
    path = tmp_path / "nearly-square.txt"
    mutation.write_ascii(str(path), heights, dx, dy)
    code, out, err = _main(["topography", str(path), "--scales", "1px,4px", "--out", str(tmp_path / "t")], capsys)
    assert code == 0, err
    assert "note: pixels square to 0.063 % (Δx = 1.85339, Δy = 1.85455 µm in the file)" in out
    doc = json.loads((tmp_path / "t" / "statistics.json").read_text())
    assert doc["field"]["square_pixels"]["pitch_as_given"] == pytest.approx([dx, dy], rel=1e-12)
    assert doc["field"]["spacing_m"] == [pytest.approx(math.sqrt(dx * dy), rel=1e-12)] * 2
    assert "treated as square" in (tmp_path / "t" / "statistics.md").read_text()


@pytest.mark.slow  # ≈ 10 s on 2 cores: a 960 × 600 field through both commands
def test_the_mountainsmap_file_works_through_topography_and_synth(tmp_path, capsys):
    code, out, err = _main(["topography", str(MNT), "--scales", "1px,4px", "--out", str(tmp_path / "t")], capsys)
    assert code == 0, err
    assert "note: pixels square to 0.063 % (Δx = 1.85339, Δy = 1.85455 µm in the file)" in out
    argv = ["synth", "--topography", str(MNT), "--scales", "1px,4px", "--pixels", "9", "--out", str(tmp_path / "m.exr")]
    code, out, err = _main(argv, capsys)
    assert code == 0, err


# -- rectangular pixels: windows of equal physical size ------------------------------------------------


def test_rectangular_windows_are_equal_to_the_tolerance_and_more_than_exact_multiples():
    """X3P's 127.7 × 314.6 nm pixels: exact common multiples start at 69 × 28 pixels; windows
    whose sides agree to 1e-3 start at 37 × 15 and give more scales."""
    dx, dy = X3P_PITCH
    field = synth.HeightField(np.zeros((400, 650)), (dx, dy), periodic=False)
    scales = field.scales(8)
    assert len(scales) >= 6  # whole multiples of 69 × 28 up to half the field: 4
    for mu in scales:
        rows, cols = field.block(mu)
        assert cols * dx == pytest.approx(mu, rel=1e-12) and abs(rows * dy - mu) <= 1e-3 * mu
    assert field.block(scales[0]) == (15, 37) and scales[0] < 69 * dx
    assert (37 * dx, 15 * dy) == (pytest.approx(4723.3e-9, abs=0.05e-9), pytest.approx(4718.7e-9, abs=0.05e-9))
    assert len(field._windows[0]) == 176 and min(649 // 69, 399 // 28) == 9  # docs/topography.md §4
    with pytest.raises(InvalidInputError, match="to a relative 0.001"):
        field.block(28 * dx)  # its y side, 11 Δy = 3460.4 nm, is 3 % from 3574.4 nm


def _plane_waves(rng, count: int):
    """Random-phase plane waves with an anisotropic spectrum: amplitudes, wave vectors (1/m), phases."""
    angle = rng.normal(0.3, 0.25, count)
    k = rng.uniform(2e5, 2.5e6, count)  # wavelengths 2.5–30 µm
    vectors = np.stack((k * np.cos(angle), 0.35 * k * np.sin(angle)), axis=-1)
    return rng.uniform(2e-9, 8e-9, count), vectors, rng.uniform(0, 2 * np.pi, count)


def _window_covariance(amplitudes, vectors, block, spacing) -> np.ndarray:
    """The expected covariance of the window-averaged forward-difference slopes over random phases.

    For ``h = A cos(k·r + φ)`` the mean of the pixel facets' −∂h over a window of ``rows × cols``
    pixel facets telescopes to ``m = Re(a e^{i(k·r₀+φ)})`` with
    ``a_x = −A (e^{i k_x L_x} − 1) D_y / L_x``, ``D_y = (1/rows) Σ_r e^{i k_y r Δy}`` (and x ↔ y),
    so ``E[m_a m_b] = Σ_waves Re(a_a a_b*) / 2``.
    """
    (rows, cols), (dx, dy) = block, spacing
    lx, ly = cols * dx, rows * dy
    kx, ky = vectors[:, 0], vectors[:, 1]
    d_y = np.mean(np.exp(1j * np.outer(ky, np.arange(rows) * dy)), axis=1)
    d_x = np.mean(np.exp(1j * np.outer(kx, np.arange(cols) * dx)), axis=1)
    a = np.stack(
        (-amplitudes * (np.exp(1j * kx * lx) - 1) * d_y / lx, -amplitudes * (np.exp(1j * ky * ly) - 1) * d_x / ly)
    )
    return np.real(a @ a.conj().T) / 2


def test_the_covariance_of_an_analytic_anisotropic_surface_is_recovered_on_rectangular_pixels():
    """Σ(μ) measured on 127.7 × 314.6 nm pixels, at windows equal to 1e-3, against the exact
    expectation for a random-phase plane-wave surface: within 4 stated standard errors."""
    dx, dy = X3P_PITCH
    ny, nx = 260, 640
    y, x = np.mgrid[0:ny, 0:nx] * np.array([dy, dx])[:, None, None]
    z = []
    for seed in range(3):
        amplitudes, vectors, phases = _plane_waves(np.random.default_rng(seed), 60)
        heights = np.einsum(
            "w,wyx->yx", amplitudes, np.cos(np.einsum("wc,cyx->wyx", vectors, np.stack((x, y))) + phases[:, None, None])
        )
        field = synth.HeightField(heights, (dx, dy), periodic=False, unit="m")
        for s in synth.facet_statistics(field, field.scales(4)[:3], bins=9):
            expected = _window_covariance(amplitudes, vectors, s.block, (dx, dy))
            assert s.window == (pytest.approx(s.block[1] * dx), pytest.approx(s.block[0] * dy))
            for a, b in ((0, 0), (1, 1), (0, 1)):
                z.append((s.covariance[a, b] - expected[a, b]) / s.covariance_error[a, b])
            assert expected[0, 0] > 3 * expected[1, 1]  # anisotropic
    z = np.array(z)
    assert np.all(np.abs(z) < 4), z
    assert abs(np.mean(z)) < 1.5  # no bias beyond the errors' own scatter


# -- the resampler -----------------------------------------------------------------------------------


def _grid(shape, spacing):
    (ny, nx), (dx, dy) = shape, spacing
    return np.mgrid[0:ny, 0:nx] * np.array([dy, dx])[:, None, None]


def test_resampling_reproduces_a_quadratic_exactly():
    quadratic = lambda x, y: 1 + 0.3 * x - 0.2 * y + 0.01 * x * x - 0.02 * y * y + 0.03 * x * y  # noqa: E731
    y, x = _grid((40, 60), (1.0, 2.4643))
    field = synth.HeightField(quadratic(x, y), (1.0, 2.4643), periodic=False)
    out = topography.resample(field)
    (x0, y0), p = out.description["origin"], out.spacing[0]
    assert out.spacing == (1.0, 1.0) and (x0, y0) == (0.0, 2.4643)  # the finer pitch; y resampled, x copied
    yy, xx = _grid(out.shape, (p, p))
    np.testing.assert_allclose(out.heights, quadratic(xx + x0, yy + y0), rtol=1e-12, atol=1e-12)
    assert out.description["interpolation"] == topography.INTERPOLATION and out.mask is None


def test_resampling_error_on_a_smooth_surface_falls_as_the_cube_of_the_pitch():
    surface = lambda x, y: np.sin(0.3 * x + 0.1 * y) + 0.5 * np.cos(0.2 * y - 0.05 * x)  # noqa: E731
    errors = []
    for s in (1.0, 0.5, 0.25):
        spacing = (1.7 * s, 2.4643 * s)
        y, x = _grid((int(50 / s), int(60 / s)), spacing)
        out = topography.resample(synth.HeightField(surface(x, y), spacing, periodic=False), pitch=1.3 * s)
        (x0, y0), p = out.description["origin"], out.spacing[0]
        yy, xx = _grid(out.shape, (p, p))
        errors.append(np.max(np.abs(out.heights - surface(xx + x0, yy + y0))))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(ratios > 6.5) and np.all(ratios < 10), (errors, ratios)  # O(Δ³): 8 per halving


def test_resampling_marks_exactly_the_nodes_that_read_an_unmeasured_pixel():
    h = np.random.default_rng(5).standard_normal((20, 20))
    mask = np.ones(h.shape, bool)
    mask[9, 11] = False
    field = synth.HeightField(h, (1.0, 1.6), mask=mask, periodic=False)
    out = topography.resample(field)
    u = 1.0 + np.arange(out.shape[0]) * 1.0 / 1.6  # the new rows' positions in old rows
    base = np.minimum(np.floor(u).astype(int), 20 - 3)
    reads = [
        j for j, (b, t) in enumerate(zip(base, u - base)) if any(b + o == 9 and abs(t - o) < 2 for o in (-1, 0, 1, 2))
    ]
    expected = np.ones(out.shape, bool)
    expected[reads, 11] = False
    np.testing.assert_array_equal(out.mask, expected)
    with pytest.raises(InvalidInputError, match="at least 4 × 4"):
        topography.resample(field, pitch=10.0)
    with pytest.raises(InvalidInputError, match="pitch"):
        topography.resample(field, pitch=-1.0)


# -- the figure ----------------------------------------------------------------------------------------


def test_the_figures_lobe_cuts_are_readable_on_an_outlier_dominated_surface():
    """One steep pixel (slope 0.8) on a surface of rms slope ≈ 0.004 (the MetroPro case): the cuts
    span the lobe, not the outlier, and every title names μ's unit."""
    rng = np.random.default_rng(6)
    h = rng.standard_normal((96, 96)) * 3e-9  # pixel slopes of rms ≈ 0.004 per axis
    h[40, 50] += 0.8e-6
    field = topography.from_array(h, 1e-6, detrend="plane")
    assert field.steepest_slope > 0.5
    stats = synth.facet_statistics(field, [1e-6, 4e-6, 16e-6], bins=65, extent=synth.robust_extent(field))
    fig = plot.facet_statistics(stats, field=field)
    nodes = np.linspace(-stats[1].lobe.extent[0], stats[1].lobe.extent[0], 65)
    for panel in fig.axes[1:3]:
        low, high = panel.get_xlim()
        assert 0.01 < high < 0.05 and np.count_nonzero((nodes > low) & (nodes < high)) >= 20
    titles = [ax.get_title() for ax in fig.axes if "μ" in ax.get_title()] + [fig._suptitle.get_text()]
    assert len(titles) >= 4 and all("µm" in t for t in titles), titles


def test_the_figures_lobe_marginals_hold_the_lobes_mass_and_smooth_a_quantised_files_comb():
    """The lobe panels draw marginals ∫ g_μ du_y, ∫ g_μ du_x: each integrates to the lobe table's
    mass (trapezoid over the drawn line against the table's own sum, which a cut through u = 0 does
    not). Heights quantised to a step that puts the slope offsets on a comb coarser than the table's
    nodes (a confocal file's case): the drawn marginals have no empty node in their core and the
    title says they are averaged; the same field unquantised is drawn as it is."""
    rng = np.random.default_rng(2)
    smooth = 0.004 * np.cumsum(np.cumsum(rng.standard_normal((128, 128)), axis=0), axis=1) / 40
    for quantum, averaged in ((None, False), (8e-4, True)):
        h = smooth if quantum is None else np.round(smooth / quantum) * quantum
        field = topography.from_array(h, 1.0, detrend="plane")
        stats = synth.facet_statistics(field, [2.0, 8.0], bins=129, extent=synth.robust_extent(field))
        fig = plot.facet_statistics(stats, field=field)
        for panel in fig.axes[1:3]:
            assert ("moving average" in panel.get_title()) is averaged, panel.get_title()
            for line, result in zip(panel.get_lines(), [r for r in stats if r.block != (1, 1)]):
                u, g = np.asarray(line.get_xdata()), np.nan_to_num(np.asarray(line.get_ydata()))
                values = np.asarray(result.lobe.values)
                step = 2 * np.asarray(result.lobe.extent) / (np.array(values.shape[::-1]) - 1)
                table = values.sum() * step[0] * step[1]  # the table's mass (rectangle rule)
                np.testing.assert_allclose(np.trapezoid(g, u), table, rtol=0.03)
                low, high = panel.get_xlim()
                core = (np.abs(u) < 0.3 * high) if averaged else slice(None, 0)
                assert np.all(g[core] > 0)
