"""The one write path (brdfscale._files) on a full disk: every step fails as OutputWriteError,
nothing is left in the target's place, an existing target stays byte-identical, no temporary
file stays behind; the command exits 8 with one line. Issue 34, build item 2.

Two ways to fill a disk: the documented test seam ``brdfscale._files._fault`` raising ENOSPC
at a chosen step (every step, every writer kind), and — as root on Linux where ``mount -t
tmpfs`` works — a real tiny tmpfs (marked slow; the kernel's own ENOSPC from each writer).
"""

import contextlib
import errno
import glob
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
import pytest
from helpers import run_command, same_set, sample_set

import brdfscale
from brdfscale import _files, exr, files, OutputWriteError
from tests.references.damage import fill, mount_tmpfs


STEPS = _files.STEPS
TOPOGRAPHY = os.path.join(os.path.dirname(__file__), "data", "topographies", "di-3.di")
_FULL = os.strerror(errno.ENOSPC)


def _figure():
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 2))
    fig.subplots().imshow(np.arange(64.0).reshape(8, 8))
    return fig


def _writers():
    """(kind, write(path, overwrite), check(path) -> bool that the file is the complete new one)."""
    mset = sample_set()
    with tempfile.TemporaryDirectory() as d:  # what a clean write reads back as (float32 pixels)
        exr.write_measurements(os.path.join(d, "m.exr"), mset)
        reference = exr.read_measurements(os.path.join(d, "m.exr"))
    doc = {"a": [1.5, float("nan")], "b": "ünïcode"}
    fig = _figure()

    def png_ok(path):
        with open(path, "rb") as f:
            head = f.read(8)
        return head == b"\x89PNG\r\n\x1a\n" and os.path.getsize(path) > 100

    return [
        (
            "exr",
            lambda p, o: exr.write_measurements(p, mset, overwrite=o),
            lambda p: same_set(exr.read_measurements(p), reference),
        ),
        (
            "json",
            lambda p, o: files.write_text(p, files.json_text(doc, indent=1), overwrite=o),
            lambda p: json.load(open(p, encoding="utf-8")) == {"a": [1.5, None], "b": "ünïcode"},
        ),
        (
            "png",
            lambda p, o: files.atomic_write(p, lambda tmp: fig.savefig(tmp, format="png"), overwrite=o),
            png_ok,
        ),
        (
            "text",
            lambda p, o: files.write_text(p, "line\n" * 100, overwrite=o),
            lambda p: open(p).read() == "line\n" * 100,
        ),
    ]


WRITERS = _writers()
SUFFIX = {"exr": ".exr", "json": ".json", "png": ".png", "text": ".md"}


def _inject(monkeypatch, at: str, code: int = errno.ENOSPC):
    seen = []

    def fault(step, tmp):
        seen.append(step)
        assert os.path.exists(tmp), "the seam is called while the temporary file exists"
        if step == at:
            raise OSError(code, os.strerror(code))

    monkeypatch.setattr(_files, "_fault", fault)
    return seen


def _leftovers(directory) -> list[str]:
    return sorted(p for p in os.listdir(directory) if ".brdfscale-" in p)


@pytest.mark.parametrize("step", STEPS)
@pytest.mark.parametrize("kind, write, check", WRITERS, ids=[w[0] for w in WRITERS])
@pytest.mark.parametrize("existing", [False, True], ids=["new", "existing"])
def test_enospc_at_every_step_leaves_the_target_untouched(tmp_path, monkeypatch, kind, write, check, step, existing):
    path = tmp_path / f"out{SUFFIX[kind]}"
    before = b"the earlier file, which must survive\n"
    if existing:
        path.write_bytes(before)
    seen = _inject(monkeypatch, step)
    with pytest.raises(OutputWriteError) as info:
        write(str(path), existing)
    err = info.value
    message = str(err)
    assert "\n" not in message
    assert message.startswith(f"{path}: not written: disk full ({_FULL})")
    assert "free on its file system" in message and isinstance(err.free, int)
    assert err.disk_full and err.errno == errno.ENOSPC and err.path == str(path)
    assert ("the existing file is unchanged" in message) == existing
    assert seen[-1] == step and seen == list(STEPS[: STEPS.index(step) + 1])  # the steps, in order
    if existing:
        assert path.read_bytes() == before
    else:
        assert not os.path.lexists(path)
    assert _leftovers(tmp_path) == []
    # the same write with the disk freed completes, replacing the earlier file only when asked
    monkeypatch.setattr(_files, "_fault", lambda step, tmp: None)
    write(str(path), existing)
    assert check(str(path)) and _leftovers(tmp_path) == []


@pytest.mark.parametrize("kind, write, check", WRITERS, ids=[w[0] for w in WRITERS])
def test_other_io_errors_are_named_as_such(tmp_path, monkeypatch, kind, write, check):
    _inject(monkeypatch, "fsync", errno.EIO)
    path = tmp_path / f"x{SUFFIX[kind]}"
    with pytest.raises(
        OutputWriteError, match=rf"^{path}: not written: {os.strerror(errno.EIO)} while syncing"
    ) as info:
        write(str(path), False)
    assert not info.value.disk_full and "disk full" not in str(info.value)
    assert os.listdir(tmp_path) == []


def test_a_writer_that_fails_itself_or_writes_nothing(tmp_path):
    path = tmp_path / "x.bin"

    def half_then_full(tmp):  # what a writer meeting a full disk does: some bytes, then ENOSPC
        with open(tmp, "wb") as f:
            f.write(b"x" * 10)
        raise OSError(errno.ENOSPC, _FULL, tmp)

    with pytest.raises(OutputWriteError, match="disk full"):
        files.atomic_write(path, half_then_full)
    with pytest.raises(OutputWriteError, match=r"holds 0 bytes after writing"):
        files.atomic_write(path, lambda tmp: None)  # never a renamed empty file
    # a foreign writer's exception type (OpenEXR's RuntimeError) quoting the OS's words
    with pytest.raises(OutputWriteError, match="disk full"):
        files.atomic_write(
            path, lambda tmp: (_ for _ in ()).throw(RuntimeError(f"write failed. {_FULL}.")), foreign=(RuntimeError,)
        )
    # other exceptions from the writer (a bug, bad input) pass unchanged, the temporary removed
    with pytest.raises(ZeroDivisionError):
        files.atomic_write(path, lambda tmp: 1 / 0)
    assert os.listdir(tmp_path) == []


def test_a_short_write_is_refused(tmp_path, monkeypatch):
    path = tmp_path / "x.txt"

    class Short:
        def __init__(self, f):
            self.f = f

        def __getattr__(self, name):
            return getattr(self.f, name)

        def write(self, data):
            return self.f.write(data[:-1])

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

    real_open = open
    monkeypatch.setattr(_files, "open", lambda *a, **k: Short(real_open(*a, **k)), raising=False)
    with pytest.raises(OutputWriteError, match="short write"):
        files.write_text(path, "abc")
    assert os.listdir(tmp_path) == []


def test_a_write_lost_in_a_destructor_fails_the_write(tmp_path):
    """h5py reports a full disk met while closing from a destructor ("Exception ignored in"):
    Python can only print it. A write during which that happened failed, though ``write``
    returned."""
    path = tmp_path / "x.bin"

    class Closing:
        def __del__(self):
            raise OSError(errno.ENOSPC, "Driver write request failed")

    def write(tmp):
        with open(tmp, "wb") as f:
            f.write(b"data")
        Closing()  # collected at once: its exception is unraisable

    hook = sys.unraisablehook
    with pytest.raises(OutputWriteError, match="disk full"):
        files.atomic_write(path, write)
    assert sys.unraisablehook is hook and os.listdir(tmp_path) == []


def test_require_free_space_and_free_space(tmp_path):
    free = files.free_space(tmp_path / "not" / "yet")  # the nearest existing parent is asked
    assert isinstance(free, int) and free > 0
    assert files.require_free_space(tmp_path, 1) > 0
    with pytest.raises(OutputWriteError, match=r"not written: disk full \(.* free on its file system, the chain needs"):
        files.require_free_space(tmp_path / "chain.h5", 1 << 62, what="chain")
    err = files.write_failed(tmp_path / "c.h5", OSError(errno.EDQUOT, os.strerror(errno.EDQUOT)))
    assert isinstance(err, OutputWriteError) and err.disk_full and "disk full (Disk quota exceeded)" in str(err)


def test_the_error_is_public_and_a_brdfscale_error():
    assert brdfscale.OutputWriteError is OutputWriteError
    assert issubclass(OutputWriteError, brdfscale.BrdfscaleError) and not issubclass(OutputWriteError, OSError)


# -- the command ---------------------------------------------------------------------------------


@pytest.mark.parametrize("step", ["write", "fsync", "rename"])
def test_the_command_exits_8_with_one_line_and_a_rerun_completes(tmp_path, monkeypatch, step):
    out = tmp_path / "x.exr"
    argv = ["synth", "gaussian", "--out", str(out), "--size", "64", "--scales", "4", "--pixels", "9"]
    _inject(monkeypatch, step)
    code, err = run_command(argv)
    assert code == 8, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"brdfscale synth: error: {out}: not written: disk full"), err
    assert os.listdir(tmp_path) == []
    monkeypatch.setattr(_files, "_fault", lambda step, tmp: None)
    code, err = run_command(argv)
    assert code == 0, err
    exr.read_measurements(out)


def test_all_or_none_removes_only_the_new_files_of_a_failed_group(tmp_path, monkeypatch):
    a, b, c = (tmp_path / n for n in ("a.txt", "b.txt", "c.txt"))
    c.write_text("the user's")
    written = []

    def fault(step, tmp):
        if step == "rename":
            written.append(tmp)
            if len(written) == 2:
                raise OSError(errno.ENOSPC, _FULL)

    monkeypatch.setattr(_files, "_fault", fault)
    with pytest.raises(OutputWriteError, match="b.txt: not written: disk full"):
        with files.all_or_none(a, b, c):
            files.write_text(a, "first")
            files.write_text(b, "second")
    assert sorted(os.listdir(tmp_path)) == ["c.txt"] and c.read_text() == "the user's"
    with files.all_or_none(a, b):  # without an error: both stay
        files.write_text(a, "1")
        files.write_text(b, "2")
    assert a.read_text() + b.read_text() == "12"


def test_topography_full_at_its_second_file_leaves_none_and_reruns_without_force(tmp_path, monkeypatch):
    out = tmp_path / "t"
    argv = ["topography", TOPOGRAPHY, "--scales", "1px,4px", "--bins", "17", "--out", str(out)]
    written = []

    def fault(step, tmp):
        if step == "write" and ".holder.json" not in tmp:
            written.append(tmp)
            if len(written) == 2:
                raise OSError(errno.ENOSPC, _FULL)

    monkeypatch.setattr(_files, "_fault", fault)
    code, err = run_command(argv)
    assert code == 8 and len(err.strip().splitlines()) == 1 and "statistics.md: not written: disk full" in err, err
    assert [p for p in os.listdir(out) if not p.startswith(".brdfscale.lock")] == []
    monkeypatch.setattr(_files, "_fault", lambda step, tmp: None)
    code, err = run_command(argv)
    assert code == 0, err
    assert sorted(p for p in os.listdir(out) if not p.startswith(".")) == [
        "statistics.json",
        "statistics.md",
        "statistics.png",
    ]


def test_a_full_disk_met_outside_the_writers_is_no_unexpected_failure(monkeypatch, capsys):
    from brdfscale import _cli

    def boom(args):
        raise OSError(errno.ENOSPC, _FULL, "/scratch/file")

    parser = _cli.build_parser
    monkeypatch.setattr(_cli, "build_parser", lambda: _with(parser(), boom))
    assert _cli.main(["--no-compilation-cache", "info", "x"]) == 8
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("brdfscale info: error: /scratch/file: not written: disk full"), err


def _with(parser, func):
    parser.subcommands["info"].set_defaults(func=func)
    return parser


# -- a real full file system ----------------------------------------------------------------------


@contextlib.contextmanager
def _tmpfs(size: str):
    where = tempfile.mkdtemp(prefix="brdfscale-tmpfs-")
    why_not = mount_tmpfs(where, size)
    if why_not is not None:
        os.rmdir(where)
        pytest.skip(f"{why_not}; the injected ENOSPC covers the steps")
    try:
        yield where
    finally:
        subprocess.run(["umount", where], check=False)
        os.rmdir(where)


def _fill(directory: str, leave: int) -> str:
    """Fill ``directory``'s file system until ``leave`` bytes are free (0: until ENOSPC); the
    library's measure of the free space agrees."""
    filler = fill(directory, leave)
    assert files.free_space(directory) == leave
    return filler


@pytest.mark.slow
@pytest.mark.parametrize("kind, write, check", WRITERS, ids=[w[0] for w in WRITERS])
@pytest.mark.parametrize("leave", [0, 4096, 16384])
def test_a_real_full_tmpfs(kind, write, check, leave):
    """The kernel's ENOSPC, from whichever step meets it: the library's error and the earlier
    file intact, or (where the file fits) the complete new file; never anything between."""
    with _tmpfs("1m") as where:
        path = os.path.join(where, f"out{SUFFIX[kind]}")
        with open(path, "wb") as f:
            f.write(b"earlier")
        filler = _fill(where, leave)
        try:
            write(path, True)
        except OutputWriteError as err:
            assert str(err).startswith(f"{path}: not written: disk full") and "the existing file is unchanged" in str(
                err
            )
            assert open(path, "rb").read() == b"earlier"
        else:
            assert leave > 0 and check(path)
        assert _leftovers(where) == []
        os.unlink(filler)
        write(path, True)
        assert check(path) and _leftovers(where) == []
        assert not glob.glob(os.path.join(where, ".*"))
