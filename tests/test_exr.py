"""Tests of brdfscale.exr: round trips, independent readers, damaged and malformed files.

Independent references: Debian's `exrheader` (C++ OpenEXR tools), a plain OpenEXR.File
reader, and files built by hand with OpenEXR.File to inject wrong attributes, missing
channels and silently changed pixels.
"""

import json
import os
import shutil
import subprocess
import sys
import types
import warnings

import hypothesis.strategies as st
import numpy as np
import OpenEXR
import pytest
from hypothesis import given, HealthCheck, settings

from brdfscale import exr, InvalidInputError, LobeImage, lobes, MeasurementSet
from brdfscale._errors import MeasurementFileError, OutputWriteError


MU = 0.1 + 1e-12  # not representable in float32: must come back exactly


def _mset(rgb=False, n=9, seed=0):
    rng = np.random.default_rng(seed)
    shape = (n, n, 3) if rgb else (n, n)
    images = []
    for k, (mu, theta) in enumerate([(MU, 0.0), (MU, 0.4), (3.7, 0.2)]):
        incident = np.array([np.sin(theta) * np.cos(k), np.sin(theta) * np.sin(k), np.cos(theta)])
        values = rng.uniform(0, 5, shape)
        sigma = rng.uniform(0.1, 1, shape) if k != 1 else None
        mask = rng.uniform(size=(n, n)) > 0.2 if k != 2 else None
        images.append(LobeImage(mu=mu, incident=incident, extent=0.05 + k / 3, values=values, sigma=sigma, mask=mask))
    return MeasurementSet(tuple(images), {"surface": "test", "numbers": [1.5, 1e-300, -2], "nested": {"a": None}})


def _assert_same(read, mset, dtype):
    assert len(read.images) == len(mset.images)
    assert read.metadata == mset.metadata
    for a, b in zip(read.images, mset.images):
        assert a.mu == b.mu and a.extent == b.extent  # doubles kept as doubles
        assert np.array_equal(a.incident, b.incident)
        np.testing.assert_array_equal(a.values, b.values.astype(dtype).astype(float))
        if b.sigma is None:
            assert a.sigma is None
        else:
            np.testing.assert_array_equal(a.sigma, b.sigma.astype(dtype).astype(float))
        assert (a.mask is None) == (b.mask is None)
        if b.mask is not None:
            assert np.array_equal(a.mask, b.mask)


@pytest.mark.parametrize("rgb", [False, True])
@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_round_trip(tmp_path, rgb, dtype):
    mset = _mset(rgb)
    path = tmp_path / "set.exr"
    exr.write_measurements(path, mset, dtype=dtype)
    read = exr.read_measurements(path)
    _assert_same(read, mset, np.float32 if dtype == "float32" else np.float16)
    assert read.images[0].mu == MU and float(np.float32(MU)) != MU
    assert exr.file_kind(path) == "measurement_set"
    assert [p for p in os.listdir(tmp_path)] == ["set.exr"]  # no temporary file left behind


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    n=st.integers(2, 12),
    mu=st.floats(1e-9, 1e9, allow_nan=False),
    extent=st.floats(1e-6, 10.0),
    theta=st.floats(0.0, 1.5),
    phi=st.floats(-3.0, 3.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_round_trip_property(tmp_path, n, mu, extent, theta, phi, seed):
    rng = np.random.default_rng(seed)
    incident = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    values = rng.standard_normal((n, n)) * 10.0 ** rng.uniform(-20, 20)
    image = LobeImage(
        mu=mu,
        incident=incident / np.linalg.norm(incident),
        extent=extent,
        values=values.astype(np.float32).astype(float),
    )
    mset = MeasurementSet((image,), {"seed": seed})
    path = tmp_path / f"p{seed}.exr"
    exr.write_measurements(path, mset, overwrite=True)
    _assert_same(exr.read_measurements(path), mset, np.float32)


def test_no_overwrite_unless_asked(tmp_path):
    path = tmp_path / "set.exr"
    path.write_bytes(b"precious")
    with pytest.raises(MeasurementFileError, match="exists.*overwrite=True"):
        exr.write_measurements(path, _mset())
    assert path.read_bytes() == b"precious"
    exr.write_measurements(path, _mset(), overwrite=True)
    assert exr.read_measurements(path).images[0].mu == MU
    assert sorted(os.listdir(tmp_path)) == ["set.exr"]
    with pytest.raises(MeasurementFileError, match="does not exist"):
        exr.write_measurements(tmp_path / "nowhere" / "x.exr", _mset())


def test_exrheader_reads_the_file(tmp_path):
    if shutil.which("exrheader") is None:
        pytest.skip("Debian's exrheader is not installed (apt-get install openexr; .ci/run installs it)")
    path = tmp_path / "set.exr"
    exr.write_measurements(path, _mset(rgb=True))
    out = subprocess.run(["exrheader", str(path)], capture_output=True, text=True, check=True).stdout
    assert out.count("brdfscale.mu (type double)") == 3
    assert "brdfscale.incident (type v3d)" in out and "brdfscale.part_count (type int): 3" in out
    assert '"lobe0002"' in out and "sigma.G, 32-bit floating-point" in out and "mask, 32-bit unsigned integer" in out
    if shutil.which("exrmaketiled"):  # decodes every pixel of every part
        result = subprocess.run(
            ["exrmaketiled", str(path), str(tmp_path / "tiled.exr")], capture_output=True, text=True, check=False
        )
        assert result.returncode == 0, result.stderr


def test_plain_openexr_reader_sees_the_layout(tmp_path):
    mset = _mset()
    path = tmp_path / "set.exr"
    exr.write_measurements(path, mset)
    f = OpenEXR.File(str(path), separate_channels=True)
    assert len(f.parts) == 3
    for part, image in zip(f.parts, mset.images):
        np.testing.assert_array_equal(part.channels["Y"].pixels, image.values.astype(np.float32))
        assert part.header["brdfscale.mu"][0] == image.mu
        np.testing.assert_array_equal(part.header["brdfscale.incident"], image.incident)
        assert part.header["brdfscale.domain"] == "half_slope"
    assert np.array_equal(f.parts[0].channels["mask"].pixels, mset.images[0].mask.astype(np.uint32))
    assert json.loads(f.parts[0].header["brdfscale.metadata"]) == mset.metadata


def _rewrite(src, dst, edit):
    """Copy an EXR part by part through OpenEXR.File, letting ``edit(index, header, channels)`` tamper."""
    f = OpenEXR.File(str(src), separate_channels=True)
    parts = []
    for k, part in enumerate(f.parts):
        header = {key: value for key, value in part.header.items() if key not in ("channels", "chunkCount", "name")}
        channels = {name: c.pixels.copy() for name, c in part.channels.items()}
        edit(k, header, channels)
        parts.append(OpenEXR.Part(header, channels, name=part.header["name"]))
    OpenEXR.File(parts).write(str(dst))


@pytest.fixture
def written(tmp_path):
    path = tmp_path / "good.exr"
    exr.write_measurements(path, _mset(rgb=True))
    return path


def _set(key, value, part=1):
    def edit(k, header, channels):
        if k == part:
            if value is None:
                del header[key]
            else:
                header[key] = value

    return edit


@pytest.mark.parametrize(
    "edit, match",
    [
        (_set("brdfscale.mu", 0.5), r"part 1 \('lobe0001'\): attribute 'brdfscale.mu': must be a double"),
        (_set("brdfscale.mu", np.array([-1.0])), r"'brdfscale.mu': must be a positive finite"),
        (_set("brdfscale.mu", None), r"part 1 .*'brdfscale.mu': missing"),
        (_set("brdfscale.extent", np.array([np.inf])), r"'brdfscale.extent': must be a positive finite"),
        (_set("brdfscale.incident", np.array([0.0, 0.6, 0.6])), r"'brdfscale.incident': must be a unit vector"),
        (_set("brdfscale.incident", np.array([0.0, 0.0, 1.0], np.float32)), r"'brdfscale.incident': must be a V3d"),
        (_set("brdfscale.domain", "direction"), r"'brdfscale.domain': must be 'half_slope'"),
        (_set("brdfscale.version", 99), r"'brdfscale.version': layout version 99"),
        (_set("brdfscale.kind", "lobe_table", part=0), r"part 0 .*'brdfscale.kind': must be 'measurement_set'"),
        (_set("brdfscale.part_index", 2), r"'brdfscale.part_index'"),
        (_set("brdfscale.part_count", 4, part=2), r"part 2 .*'brdfscale.part_count': declares 4"),
        (_set("brdfscale.metadata", "{not json", part=0), r"part 0 .*'brdfscale.metadata': is not valid JSON"),
        (_set("brdfscale.checksums", "[]"), r"'brdfscale.checksums': must be a JSON object"),
    ],
)
def test_wrong_attributes_are_named(written, tmp_path, edit, match):
    bad = tmp_path / "bad.exr"
    _rewrite(written, bad, edit)
    with pytest.raises(MeasurementFileError, match=match) as info:
        exr.read_measurements(bad)
    assert str(bad) in str(info.value)


def test_untampered_rewrite_reads(written, tmp_path):
    """The tampering helper itself preserves a valid file (so the failures above are the edits')."""
    copy = tmp_path / "copy.exr"
    _rewrite(written, copy, lambda k, h, c: None)
    _assert_same(exr.read_measurements(copy), _mset(rgb=True), np.float32)


def _drop(channel, part=0):
    def edit(k, header, channels):
        if k == part:
            del channels[channel]

    return edit


@pytest.mark.parametrize(
    "edit, match",
    [
        (_drop("G"), r"part 0 .*channel 'G': missing"),
        (_drop("sigma.B"), r"part 0 .*channel 'sigma.B': missing"),
        (lambda k, h, c: c.update(extra=np.zeros((9, 9), np.float32)), r"unexpected channel\(s\) \['extra'\]"),
        (lambda k, h, c: c.update(Y=np.zeros((9, 9), np.float32)), r"has both Y and R/G/B"),
        (lambda k, h, c: c.update(mask=np.full((9, 9), 2, np.uint32)) if k == 0 else None, r"channel 'mask'"),
    ],
)
def test_missing_or_unexpected_channels(written, tmp_path, edit, match):
    bad = tmp_path / "bad.exr"
    _rewrite(written, bad, edit)
    with pytest.raises(MeasurementFileError, match=match):
        exr.read_measurements(bad)


def test_silently_changed_pixels_fail_the_checksum(written, tmp_path):
    bad = tmp_path / "bad.exr"

    def edit(k, header, channels):
        if k == 2:
            channels["R"][4, 4] = np.nextafter(channels["R"][4, 4], np.float32(np.inf))

    _rewrite(written, bad, edit)
    with pytest.raises(
        MeasurementFileError, match=r"part 2 .*channel 'R': pixel data do not match the stored checksum"
    ):
        exr.read_measurements(bad)


@pytest.mark.parametrize("fraction", [0.02, 0.3, 0.6, 0.9, 0.999])
def test_truncated_files(written, tmp_path, fraction):
    data = written.read_bytes()
    bad = tmp_path / "cut.exr"
    bad.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(MeasurementFileError, match=r"cut\.exr: (not a readable OpenEXR|no readable part|.*truncated)"):
        exr.read_measurements(bad)


@pytest.mark.parametrize("fraction", [0.6, 0.9, 0.999])
def test_damaged_file_prints_nothing_and_costs_one_line(written, tmp_path, capfd, fraction):
    """A file cut inside its pixel data: OpenEXR's C++ layer prints on file descriptors 1 and 2
    (four lines for two damaged parts); the reader captures them, so nothing reaches the
    descriptors and the error is one line carrying OpenEXR's first diagnostic
    (brdfscale/exr/_diagnostics.py)."""
    data = written.read_bytes()
    bad = tmp_path / "cut.exr"
    bad.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(MeasurementFileError) as info:
        exr.read_measurements(bad)
    out, err = capfd.readouterr()
    assert (out, err) == ("", "")
    message = str(info.value)
    assert "\n" not in message and "truncated" in message
    assert "(OpenEXR: (EXR_ERR_" in message and str(bad) + ": (" not in message  # the path is said once
    # and the descriptors work as before afterwards
    os.write(1, b"after\n")
    assert capfd.readouterr().out == "after\n"


def test_a_command_on_a_damaged_file_prints_one_line(written, tmp_path):
    """Through the ``brdfscale`` command in a fresh process: one line in all, on stderr."""
    data = written.read_bytes()
    bad = tmp_path / "cut.exr"
    bad.write_bytes(data[: int(len(data) * 0.6)])
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from brdfscale._cli import main; sys.exit(main(sys.argv[1:]))",
            "--no-compilation-cache",
            "info",
            str(bad),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode != 0 and out.stdout == ""
    assert out.stderr.count("\n") == 1 and "cut.exr" in out.stderr, out.stderr


@pytest.mark.parametrize("seed", range(6))
def test_garbled_bytes_never_pass_silently(written, tmp_path, seed):
    """Random bytes overwritten after the headers: an OpenEXR error or a checksum mismatch."""
    data = bytearray(written.read_bytes())
    rng = np.random.default_rng(seed)
    start = len(data) // 2
    positions = rng.integers(start, len(data), 8)
    for p in positions:
        data[p] ^= int(rng.integers(1, 256))
    bad = tmp_path / "garbled.exr"
    bad.write_bytes(bytes(data))
    with pytest.raises(MeasurementFileError, match="garbled.exr"):
        exr.read_measurements(bad)


def test_not_an_exr_and_missing(tmp_path):
    junk = tmp_path / "junk.exr"
    junk.write_text("hello")
    with pytest.raises(MeasurementFileError, match="junk.exr: not a readable OpenEXR"):
        exr.read_measurements(junk)
    with pytest.raises(MeasurementFileError, match="no such file"):
        exr.read_measurements(tmp_path / "absent.exr")
    foreign = tmp_path / "foreign.exr"
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"Y": np.zeros((4, 4), np.float32)}).write(str(foreign))
    with pytest.raises(MeasurementFileError, match=r"'brdfscale.format': missing"):
        exr.read_measurements(foreign)


@pytest.mark.wrong_types
def test_write_names_what_is_not_a_measurement_set(tmp_path):
    with pytest.raises(InvalidInputError, match="MeasurementSet"):
        exr.write_measurements(tmp_path / "a.exr", {"images": []})
    assert not (tmp_path / "a.exr").exists()


def test_write_rejects_bad_input(tmp_path):
    bad_meta = MeasurementSet(_mset().images, {"x": np.float32(1.0)})
    with pytest.raises(InvalidInputError, match="JSON"):
        exr.write_measurements(tmp_path / "a.exr", bad_meta)
    big = MeasurementSet((LobeImage(mu=1.0, incident=[0, 0, 1.0], extent=1.0, values=np.full((3, 3), 1e5)),))
    with pytest.raises(InvalidInputError, match="float16"):
        exr.write_measurements(tmp_path / "a.exr", big, dtype="float16")
    with pytest.raises(InvalidInputError, match="dtype"):
        exr.write_measurements(tmp_path / "a.exr", big, dtype="float64")
    assert not (tmp_path / "a.exr").exists()


def test_lobe_table_round_trip(tmp_path):
    scales = [0.5, 2.0 + 1e-13, 8.0]
    table = exr.LobeTable.from_lobes(
        scales,
        [lobes.Beckmann(a, amplitude=0.9) for a in (0.05, 0.03, 0.02)],
        extent=0.2,
        size=33,
        metadata={"law": "test"},
    )
    x = np.linspace(-0.2, 0.2, 33)
    u = np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)
    np.testing.assert_allclose(
        table.values[1], 0.9 * np.exp(-np.sum(u**2, -1) / 0.03**2) / (np.pi * 0.03**2), rtol=1e-12
    )
    path = tmp_path / "table.exr"
    exr.write_lobe_table(path, table)
    read = exr.read_lobe_table(path)
    assert read.scales.tolist() == scales and read.extent == 0.2 and read.metadata == {"law": "test"}
    np.testing.assert_array_equal(read.values, table.values.astype(np.float32).astype(float))
    assert exr.file_kind(path) == "lobe_table"
    with pytest.raises(MeasurementFileError, match=r"'brdfscale.kind': must be 'measurement_set'"):
        exr.read_measurements(path)
    mpath = tmp_path / "m.exr"
    exr.write_measurements(mpath, _mset())
    with pytest.raises(MeasurementFileError, match=r"'brdfscale.kind': must be 'lobe_table'"):
        exr.read_lobe_table(mpath)
    bad = tmp_path / "bad.exr"
    _rewrite(path, bad, _set("brdfscale.extent", np.array([0.3]), part=2))
    with pytest.raises(MeasurementFileError, match="part 2 .*a table has one grid"):
        exr.read_lobe_table(bad)
    with pytest.raises(InvalidInputError, match="distinct"):
        exr.LobeTable([1.0, 1.0], 0.1, np.zeros((2, 3, 3)))


def test_images_of_different_sizes(tmp_path):
    mset = MeasurementSet(
        (
            LobeImage(mu=1.0, incident=[0, 0, 1.0], extent=0.1, values=np.arange(25.0).reshape(5, 5)),
            LobeImage(
                mu=2.0, incident=[0, 0, 1.0], extent=0.2, values=np.arange(81.0).reshape(9, 9), sigma=np.ones((9, 9))
            ),
        )
    )
    path = tmp_path / "mixed.exr"
    exr.write_measurements(path, mset)
    _assert_same(exr.read_measurements(path), mset, np.float32)


def _one(values, sigma=None, metadata=None):
    image = LobeImage(mu=1.0, incident=[0, 0, 1.0], extent=1.0, values=values, sigma=sigma)
    return MeasurementSet((image,), {} if metadata is None else metadata)


@pytest.mark.parametrize("dtype, big", [("float32", 1e39), ("float16", 7e4)])
def test_values_beyond_the_stored_range_are_refused(tmp_path, dtype, big):
    """A finite value or σ that the cast turns into inf is refused (was: inf written, RuntimeWarning)."""
    path = tmp_path / "big.exr"
    values = np.ones((3, 3))
    values[1, 2] = -big
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy overflow warning either
        with pytest.raises(
            InvalidInputError, match=rf"image 0 values \(channel Y\): 1 entries .*exceed the {dtype} range"
        ):
            exr.write_measurements(path, _one(values), dtype=dtype)
        with pytest.raises(InvalidInputError, match=rf"image 0 sigma .*exceed the {dtype} range"):
            exr.write_measurements(path, _one(np.ones((3, 3)), sigma=np.full((3, 3), big)), dtype=dtype)
    assert not path.exists()
    hint = "rescale" if dtype == "float32" else "dtype='float32'"
    with pytest.raises(InvalidInputError, match=hint):
        exr.write_measurements(path, _one(values), dtype=dtype)
    exr.write_measurements(path, _one(np.full((3, 3), 3.4e38)))  # the float32 maximum itself fits
    assert np.all(np.isfinite(exr.read_measurements(path).images[0].values))


def test_values_underflowing_to_zero_are_refused(tmp_path):
    """Nonzero values that the cast turns into 0 are refused as σ's are, unless negligible
    against the channel's largest value (a lobe's far tail)."""
    path = tmp_path / "small.exr"
    with pytest.raises(
        InvalidInputError, match=r"image 0 values \(channel Y\): 9 nonzero entries .*underflow to 0 in float16"
    ):
        exr.write_measurements(path, _one(np.full((3, 3), 1e-9)), dtype="float16")
    rgb = np.ones((3, 3, 3))
    rgb[..., 2] = 1e-9  # one channel lost entirely
    with pytest.raises(InvalidInputError, match=r"channel B\).*underflow to 0 in float16.*dtype='float32'"):
        exr.write_measurements(path, _one(rgb), dtype="float16")
    with pytest.raises(InvalidInputError, match=r"sigma \(channel sigma\).*underflow to 0 in float16"):
        exr.write_measurements(path, _one(np.ones((3, 3)), sigma=np.full((3, 3), 1e-9)), dtype="float16")
    with pytest.raises(InvalidInputError, match="underflow to 0 in float32.*rescale"):
        exr.write_measurements(path, _one(np.full((3, 3), 1e-46)))
    assert not path.exists()
    tail = np.ones((3, 3))
    tail[0, 0] = 1e-60  # below float32 precision relative to the largest value: a tail, stored as 0
    exr.write_measurements(path, _one(tail))
    read = exr.read_measurements(path).images[0].values
    assert read[0, 0] == 0 and read[1, 1] == 1
    exr.write_measurements(path, _one(np.full((3, 3), 1e-9)), overwrite=True)  # fits float32
    assert np.all(exr.read_measurements(path).images[0].values > 0)


@pytest.mark.wrong_types
def test_metadata_must_be_a_mapping():
    with pytest.raises(InvalidInputError, match="metadata must be a dict.*got list"):
        _one(np.ones((3, 3)), metadata=[1, 2])
    with pytest.raises(InvalidInputError, match="metadata must be a dict.*got NoneType"):
        MeasurementSet(_mset().images, None)
    with pytest.raises(InvalidInputError, match="metadata must be a dict.*got list"):
        exr.LobeTable([1.0], 0.1, np.ones((1, 3, 3)), [1, 2])


def test_metadata_must_be_a_json_object(tmp_path):
    path = tmp_path / "m.exr"
    with pytest.raises(InvalidInputError, match=r"keys must be strings.*int key 2 in metadata\['a'\]"):
        exr.write_measurements(path, _one(np.ones((3, 3)), metadata={"a": {2: "two"}}))
    with pytest.raises(InvalidInputError, match="keys must be strings"):
        exr.write_lobe_table(path, exr.LobeTable([1.0], 0.1, np.ones((1, 3, 3)), {1: "x", "y": 2}))
    mset = _one(np.ones((3, 3)), metadata={"a": 1})
    mset.metadata["later"] = [1, 2]  # a dict may still change: JSON is checked when written
    mset.metadata[3] = "x"
    with pytest.raises(InvalidInputError, match="keys must be strings"):
        exr.write_measurements(path, mset)
    assert not path.exists()
    proxy = _one(np.ones((3, 3)), metadata=types.MappingProxyType({"a": [1, "b"]}))
    assert type(proxy.metadata) is dict
    exr.write_measurements(path, proxy)
    assert exr.read_measurements(path).metadata == {"a": [1, "b"]}


def test_bad_paths_are_named(tmp_path):
    folder = tmp_path / "folder"
    folder.mkdir()
    for overwrite in (False, True):
        with pytest.raises(MeasurementFileError, match=rf"{folder}: is a directory"):
            exr.write_measurements(folder, _mset(), overwrite=overwrite)
    assert folder.is_dir() and not os.listdir(folder) and os.listdir(tmp_path) == ["folder"]
    with pytest.raises(MeasurementFileError, match=rf"{folder}: is a directory"):
        exr.read_measurements(folder)
    for bad in (None, 3, ""):
        with pytest.raises(InvalidInputError, match="path must be"):
            exr.write_measurements(bad, _mset())
        with pytest.raises(InvalidInputError, match="path must be"):
            exr.read_measurements(bad)
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(OutputWriteError, match=rf"{locked / 'x.exr'}: not written: Permission denied"):
            exr.write_measurements(locked / "x.exr", _mset())


@pytest.mark.wrong_types
def test_overwrite_must_be_a_bool(tmp_path):
    path = tmp_path / "set.exr"
    path.write_bytes(b"precious")
    with pytest.raises(InvalidInputError, match="overwrite must be True or False"):
        exr.write_measurements(path, _mset(), overwrite="no")
    assert path.read_bytes() == b"precious"


def test_lobe_table_writer_has_the_same_checks(tmp_path):
    path = tmp_path / "t.exr"
    with pytest.raises(InvalidInputError, match=r"scale 1 values \(channel Y\).*exceed the float32 range"):
        exr.write_lobe_table(path, exr.LobeTable([1.0, 2.0], 0.1, np.stack([np.ones((3, 3)), np.full((3, 3), 1e39)])))
    with pytest.raises(InvalidInputError, match=r"scale 0 values \(channel G\).*underflow to 0 in float16"):
        rgb = np.ones((1, 3, 3, 3))
        rgb[..., 1] = -1e-9
        exr.write_lobe_table(path, exr.LobeTable([1.0], 0.1, rgb), dtype="float16")
    table = exr.LobeTable([1.0], 0.1, np.ones((1, 3, 3)))
    with pytest.raises(MeasurementFileError, match=rf"{tmp_path}: is a directory"):
        exr.write_lobe_table(tmp_path, table, overwrite=True)
    with pytest.raises(InvalidInputError, match="path must be"):
        exr.write_lobe_table(None, table)
    with pytest.raises(InvalidInputError, match="path must be"):
        exr.read_lobe_table(None)
    assert os.listdir(tmp_path) == []


@pytest.mark.wrong_types
def test_lobe_table_writer_names_a_dtype_that_is_not_a_name(tmp_path):
    table = exr.LobeTable([1.0], 0.1, np.ones((1, 3, 3)))
    with pytest.raises(InvalidInputError, match="dtype must be"):
        exr.write_lobe_table(tmp_path / "t.exr", table, dtype=["float32"])
    assert os.listdir(tmp_path) == []


def test_lobe_table_from_lobes_refuses_tables_above_the_cap(monkeypatch):
    """Was: JAX RESOURCE_EXHAUSTED (8 TB) from deep inside; now refused before allocating."""
    from brdfscale.exr import _tables

    beckmann = [lobes.Beckmann(0.1)]
    with pytest.raises(
        InvalidInputError, match=r"size=1000000 needs about .* GiB.*MAX_TABLE_BYTES = 2147483648.*smaller size"
    ):
        exr.LobeTable.from_lobes([1.0], beckmann, extent=0.1, size=10**6)
    monkeypatch.setattr(_tables, "MAX_TABLE_BYTES", 8 * 3 * 33 * 33)  # one scale: table + grid = 3 planes
    assert exr.LobeTable.from_lobes([1.0], beckmann, extent=0.1, size=33).values.shape == (1, 33, 33)
    with pytest.raises(InvalidInputError, match="MAX_TABLE_BYTES"):
        exr.LobeTable.from_lobes([1.0], beckmann, extent=0.1, size=34)
    with pytest.raises(InvalidInputError, match=r"2 scale\(s\)"):
        exr.LobeTable.from_lobes([1.0, 2.0], beckmann * 2, extent=0.1, size=33)


@pytest.mark.wrong_types
def test_lobe_table_size_must_be_an_integer():
    for size in (1e6, 33.0, "33", None):
        with pytest.raises(InvalidInputError, match="size must be an integer ≥ 2"):
            exr.LobeTable.from_lobes([1.0], [lobes.Beckmann(0.1)], extent=0.1, size=size)


def test_complex_input_and_non_boolean_masks_are_refused():
    """Was: complex cast to real with a ComplexWarning only; mask=NaN or 0.5 became True."""
    ok = {"mu": 1.0, "incident": [0, 0, 1.0], "extent": 1.0, "values": np.ones((3, 3))}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning on the way to the error
        for field, bad in (
            ("values", np.ones((3, 3)) + 0j),
            ("sigma", np.ones((3, 3), complex)),
        ):
            with pytest.raises(InvalidInputError, match=rf"{field} must be real numbers.*complex"):
                LobeImage(**{**ok, field: bad})
        with pytest.raises(InvalidInputError, match=r"values must be real numbers.*complex"):
            exr.LobeTable([1.0], 0.1, np.ones((1, 3, 3)) + 0j)
        with pytest.raises(InvalidInputError, match=r"scales must be real numbers.*complex"):
            exr.LobeTable(np.array([1.0 + 0j]), 0.1, np.ones((1, 3, 3)))
    for mask in (np.full((3, 3), np.nan), np.full((3, 3), 0.5), np.full((3, 3), 2), np.full((3, 3), "yes")):
        with pytest.raises(InvalidInputError, match="mask must be boolean-valued"):
            LobeImage(**ok, mask=mask)
    image = LobeImage(**ok, mask=np.eye(3))  # 0/1 numbers are booleans
    assert image.mask.dtype == bool and image.mask.tolist() == np.eye(3, dtype=bool).tolist()
    with pytest.raises(InvalidInputError, match="values must be real numbers.*bool"):
        LobeImage(**{**ok, "values": np.ones((3, 3), bool)})


@pytest.mark.wrong_types
def test_a_complex_incident_direction_is_refused():
    """LobeImage's incident is annotated real (a real array or a sequence of floats)."""
    ok = {"mu": 1.0, "incident": [0, 0, 1.0], "extent": 1.0, "values": np.ones((3, 3))}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning on the way to the error
        with pytest.raises(InvalidInputError, match=r"incident must be real numbers.*complex"):
            LobeImage(**{**ok, "incident": np.array([0, 0, 1.0]) + 0j})


@pytest.mark.parametrize(
    "call, match",
    [
        pytest.param(
            lambda ok: LobeImage(**{**ok, "mu": "a"}),
            "mu must be a finite real number > 0; got str",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(
            lambda ok: LobeImage(**{**ok, "mu": "1"}),  # was silently converted
            "mu",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(lambda ok: LobeImage(**{**ok, "mu": None}), "mu", marks=pytest.mark.wrong_types),
        (lambda ok: LobeImage(**{**ok, "mu": True}), "mu"),
        pytest.param(lambda ok: LobeImage(**{**ok, "mu": np.array([1.0, 2.0])}), "mu", marks=pytest.mark.wrong_types),
        pytest.param(lambda ok: LobeImage(**{**ok, "extent": None}), "extent", marks=pytest.mark.wrong_types),
        pytest.param(
            lambda ok: LobeImage(**{**ok, "incident": "abc"}),
            "incident must be real numbers",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(lambda ok: LobeImage(**{**ok, "incident": None}), "incident", marks=pytest.mark.wrong_types),
        pytest.param(lambda ok: LobeImage(**{**ok, "values": "x"}), "values", marks=pytest.mark.wrong_types),
        pytest.param(
            lambda ok: LobeImage(**{**ok, "values": [[1.0, 2.0], [3.0]]}),
            "values must be an array of real numbers",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(lambda ok: LobeImage(**{**ok, "sigma": "x"}), "sigma", marks=pytest.mark.wrong_types),
        pytest.param(
            lambda ok: MeasurementSet(None),
            "images must be a non-empty sequence of LobeImage; got NoneType",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(
            lambda ok: MeasurementSet(LobeImage(**ok)),
            "images must be a non-empty sequence",
            marks=pytest.mark.wrong_types,
        ),
        (lambda ok: exr.LobeTable("a", 0.1, np.ones((1, 3, 3))), "scales"),
        pytest.param(lambda ok: exr.LobeTable(None, 0.1, np.ones((1, 3, 3))), "scales", marks=pytest.mark.wrong_types),
        pytest.param(lambda ok: exr.LobeTable([1.0], "a", np.ones((1, 3, 3))), "extent", marks=pytest.mark.wrong_types),
        pytest.param(lambda ok: exr.LobeTable([1.0], 0.1, None), "values", marks=pytest.mark.wrong_types),
        pytest.param(
            lambda ok: exr.LobeTable.from_lobes([1.0], [lobes.Beckmann(0.1)], extent="a"),
            "extent",
            marks=pytest.mark.wrong_types,
        ),
        (lambda ok: exr.LobeTable.from_lobes([1.0], [lobes.Beckmann(0.1)], extent=float("nan")), "extent"),
        (lambda ok: exr.LobeTable.from_lobes([1.0], None, extent=0.1), "lobes must be a sequence"),
        pytest.param(
            lambda ok: exr.LobeTable.from_lobes(None, [lobes.Beckmann(0.1)], extent=0.1),
            "scales",
            marks=pytest.mark.wrong_types,
        ),
        pytest.param(
            lambda ok: exr.LobeTable.from_lobes([1.0], [lobes.Beckmann(0.1)], extent=0.1, metadata=[]),
            "metadata must be a dict",
            marks=pytest.mark.wrong_types,
        ),
    ],
    ids=lambda x: x if isinstance(x, str) else "",
)
def test_constructor_arguments_of_the_wrong_type(call, match):
    """Was: bare TypeError/ValueError from float()/numpy, or a silent conversion."""
    ok = {"mu": 1.0, "incident": [0, 0, 1.0], "extent": 1.0, "values": np.ones((3, 3))}
    with pytest.raises(InvalidInputError, match=match):
        call(ok)
