"""Atomic, no-clobber file writing and exclusive output locations: the one place where
brdfscale creates files and takes locks (public as :mod:`brdfscale.files`)."""

import contextlib
import datetime
import errno
import glob
import json
import os
import shutil
import socket
import sys
import tempfile
from collections.abc import Callable, Iterator

from ._errors import BrdfscaleError, InvalidInputError, OutputInUseError, OutputWriteError


#: Temporary files are ``.<name>.brdfscale-<host>-<pid>-<random>.tmp<suffix>`` beside the target.
_TMP_MARK = ".brdfscale-"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _host() -> str:
    return "".join(c if c.isalnum() else "_" for c in socket.gethostname())[:40] or "host"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # exists, owned by someone else (or unknowable): keep its files
    return True


def _remove_stale_temporaries(directory: str, name: str) -> list[str]:
    """Remove the temporary files that interrupted writes of ``name`` left in ``directory``.

    A temporary file records the host and PID of its writer; it is stale when that host is
    this one and the process no longer exists (a killed run). Files of live processes or of
    other hosts (a shared file system) are left alone. Returns the removed paths.
    """
    removed = []
    host = _host()
    for tmp in glob.glob(os.path.join(glob.escape(directory), f".{glob.escape(name)}{_TMP_MARK}*")):
        tag = os.path.basename(tmp)[len(name) + 1 + len(_TMP_MARK) :].split("-")
        if len(tag) < 3 or tag[0] != host or not tag[1].isdigit():
            continue
        if int(tag[1]) != os.getpid() and not _alive(int(tag[1])):
            with contextlib.suppress(OSError):
                os.unlink(tmp)
                removed.append(tmp)
    return removed


#: The steps of a write, in order, as :func:`_fault` names them.
STEPS = ("write", "flush", "fsync", "close", "rename")

#: Errors that mean the file system has no room left (a full disk, a spent quota).
_FULL = frozenset(e for e in (errno.ENOSPC, getattr(errno, "EDQUOT", None)) if e is not None)


def _fault(step: str, tmp: str) -> None:
    """The test seam of every write: called just before each step of :data:`STEPS` with the
    temporary file's path (for a writer given as a callback — ``write(tmp)`` — after the
    callback returned: its own writes and flushes happened inside it). It does nothing;
    tests monkeypatch it (``monkeypatch.setattr(brdfscale._files, "_fault", ...)``) to raise
    ``OSError(errno.ENOSPC, ...)`` at a chosen step, as a full disk would. Not for other use."""


def _size(n: int | None) -> str:
    if n is None:
        return "unknown space"
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} B"


def free_space(path: str | os.PathLike) -> int | None:
    """Bytes free to this user on the file system holding ``path`` (a file or directory, which
    need not exist yet: its nearest existing parent is asked), or None when unknowable."""
    p = os.path.abspath(os.fspath(path))
    while not os.path.exists(p) and os.path.dirname(p) != p:
        p = os.path.dirname(p)
    try:
        return shutil.disk_usage(p).free
    except OSError:
        return None


def _mentions_full(err: BaseException) -> bool:
    text = str(err)
    return any(os.strerror(e) in text for e in _FULL) or "ENOSPC" in text or "EDQUOT" in text


def write_failed(
    path: str | os.PathLike, err: BaseException, *, step: str = "writing", kept: str | None = None
) -> OutputWriteError:
    """The library's error for a failed write of ``path``: one line naming the file, the
    operating system's error (ENOSPC/EDQUOT — or a foreign writer's message quoting them — as
    "disk full") and the free space on that file system. ``kept`` says what was left in the
    file's place (default: an existing file is unchanged, else nothing was written there).
    Raise it ``from err``. For writers outside :func:`atomic_write` (the h5py boundary)."""
    path = os.fspath(path)
    code = getattr(err, "errno", None)
    code = code if isinstance(code, int) else None
    if code is None and _mentions_full(err):
        code = errno.ENOSPC
    free = free_space(path)
    if code is not None and code in _FULL:
        what = f"disk full ({os.strerror(code)})"
    else:
        what = " ".join(str(getattr(err, "strerror", None) or err).split())[:200] or type(err).__name__
    if kept is None:
        kept = "the existing file is unchanged" if os.path.lexists(path) else "nothing was left in its place"
    return OutputWriteError(
        f"{path}: not written: {what} while {step}; {_size(free)} free on its file system; {kept}. "
        + ("Free some space and run again." if code in _FULL else "Check the file system and run again."),
        path=path,
        errno=code,
        free=free,
    )


def require_free_space(path: str | os.PathLike, needed: int, *, what: str = "output") -> int | None:
    """Preflight before a large write: :class:`OutputWriteError` ("disk full") when the file
    system holding ``path`` has fewer than ``needed`` bytes free, else the free bytes (None
    when the file system cannot say, which passes). Call it before writers whose own state a
    full disk would poison (HDF5), with ``needed`` at least the bytes about to be written."""
    free = free_space(path)
    if free is not None and free < needed:
        raise OutputWriteError(
            f"{os.fspath(path)}: not written: disk full ({_size(free)} free on its file system, "
            f"the {what} needs about {_size(int(needed))}); nothing was changed. Free some space and run again.",
            path=os.fspath(path),
            errno=errno.ENOSPC,
            free=free,
        )
    return free


def _sync_directory(directory: str) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return  # a directory that cannot be opened (Windows, permissions): nothing to sync
    try:
        os.fsync(fd)
    except OSError as err:
        if err.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF, errno.EACCES):
            raise
    finally:
        os.close(fd)


def atomic_write(
    path: str | os.PathLike,
    write: Callable[[str], object],
    *,
    overwrite: bool = False,
    error: type[Exception] = InvalidInputError,
    foreign: tuple[type[BaseException], ...] = (),
) -> str:
    """Write ``path`` through ``write(tmp)`` on a temporary file in the same directory.

    The one write path of brdfscale. Readers never see a half-written file: ``write`` fills
    the temporary file, which is then fsynced, checked (it must not be empty), closed and
    only then moved into place, and the directory fsynced. Without ``overwrite`` an existing
    file is never replaced: the temporary file is hard-linked to ``path``, which fails if
    ``path`` exists, even when another process creates it meanwhile. The file gets the mode
    a plain ``open`` would give (0666 less the umask). A ``path`` that exists without
    ``overwrite``, or whose directory is missing, is refused as ``error``.

    An operating-system error at any step (``OSError`` — or an exception of a ``foreign``
    type, for writers such as OpenEXR that report I/O failures in their own exceptions) is
    raised as :class:`OutputWriteError` naming the file, the error ("disk full" for
    ENOSPC/EDQUOT) and the free space; the temporary file is removed and ``path`` is left
    as it was (tests/test_disk_full.py, at every step and on a real full tmpfs). Other
    exceptions from ``write`` pass unchanged, the temporary file removed likewise. For
    bytes or text in hand use :func:`write_bytes`/:func:`write_text`, which also check that
    every byte was written.

    The temporary file is ``.<name>.brdfscale-<host>-<pid>-<random>.tmp<suffix>``: a process
    killed mid-write (SIGKILL: no ``finally`` runs) leaves it behind, visibly named after its
    target, and the next write to the same ``path`` removes it (tested in
    tests/test_robustness.py).
    """

    def fill(tmp: str) -> None:
        with _lost_errors() as lost:
            write(tmp)
        if lost:  # the writer returned, but a write failed where only a destructor saw it
            first = lost[0]
            if isinstance(first, OSError):
                raise first
            raise OSError(errno.ENOSPC if _mentions_full(first) else errno.EIO, " ".join(str(first).split()))
        _fault("write", tmp)
        _fault("flush", tmp)

    return _write(path, fill, None, overwrite, error, foreign)


@contextlib.contextmanager
def _lost_errors() -> Iterator[list[BaseException]]:
    """Collect the OSErrors raised where Python can only print them while a writer runs (a C
    library's destructor: h5py's "Exception ignored in ... __dealloc__" on a full disk).
    A write that lost one failed even when the writer returned; and when the writer raised
    its own error they are the same failure, not printed a second time."""
    lost: list[BaseException] = []
    previous = sys.unraisablehook

    def hook(unraisable):
        if isinstance(unraisable.exc_value, (OSError, RuntimeError)):  # h5py's destructors raise both
            lost.append(unraisable.exc_value)
        else:
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        yield lost
    finally:
        sys.unraisablehook = previous


def write_bytes(
    path: str | os.PathLike, data: bytes, *, overwrite: bool = False, error: type[Exception] = InvalidInputError
) -> str:
    """Write ``data`` to ``path`` through :func:`atomic_write`'s steps, checking that every
    byte reached the file (a short write is an :class:`OutputWriteError`)."""
    data = bytes(data)

    def fill(tmp: str) -> None:
        with open(tmp, "wb") as f:
            _fault("write", tmp)
            if f.write(data) != len(data):
                raise OSError(errno.EIO, f"short write to {tmp}")
            _fault("flush", tmp)
            f.flush()

    return _write(path, fill, len(data), overwrite, error, ())


def write_text(
    path: str | os.PathLike,
    text: str,
    *,
    overwrite: bool = False,
    error: type[Exception] = InvalidInputError,
    encoding: str = "utf-8",
) -> str:
    """Write ``text`` (encoded as ``encoding``) to ``path``: :func:`write_bytes`."""
    return write_bytes(path, text.encode(encoding), overwrite=overwrite, error=error)


def file_path(path, what: str = "a file") -> str:
    """``path`` as a str (bytes decoded as the file system does), or InvalidInputError when it cannot name a file:
    not a str, bytes or os.PathLike, empty, or holding a NUL character. Every write goes through it
    (:func:`atomic_write`), and brdfscale.exr's readers too."""
    try:
        p = os.fspath(path)
    except TypeError:
        raise InvalidInputError(
            f"path must be a str or os.PathLike naming {what}; got {type(path).__name__} {path!r:.80}."
        ) from None
    if isinstance(p, bytes):
        p = os.fsdecode(p)
    if not p or "\0" in p:
        raise InvalidInputError(f"path must be a non-empty file name without NUL characters; got {p!r:.80}.")
    return p


def _write(path, fill, expected: int | None, overwrite: bool, error, foreign) -> str:
    path = file_path(path)
    if not overwrite and os.path.lexists(path):
        raise error(f"{path}: file exists; pass overwrite=True to replace it.")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise error(f"{path}: directory {directory} does not exist.")
    name = os.path.basename(path)
    _remove_stale_temporaries(directory, name)
    suffix = os.path.splitext(path)[1]
    step = "creating a temporary file"
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(
            dir=directory, prefix=f".{name}{_TMP_MARK}{_host()}-{os.getpid()}-", suffix=".tmp" + suffix
        )
        os.close(fd)
        step = "writing"
        fill(tmp)
        step = "syncing to disk"
        fd = os.open(tmp, os.O_RDONLY)
        try:
            _fault("fsync", tmp)
            os.fsync(fd)
            size = os.fstat(fd).st_size
        except BaseException:
            os.close(fd)
            raise
        step = "closing"
        _fault("close", tmp)
        os.close(fd)
        step = "checking"
        if size == 0 or (expected is not None and size != expected):
            raise OSError(
                errno.EIO,
                f"the file holds {size} bytes after writing"
                + (f" {expected}" if expected is not None else "")
                + " (a writer that lost its data)",
            )
        os.chmod(tmp, 0o666 & ~_umask())
        step = "moving it into place"
        _fault("rename", tmp)
        if overwrite:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)
            except FileExistsError:
                raise error(f"{path}: file exists; pass overwrite=True to replace it.") from None
        step = "syncing its directory"
        _sync_directory(directory)
    except BrdfscaleError:
        raise
    except OSError as err:
        _remove(tmp)
        kept = "the file is in place but may not survive a crash" if step == "syncing its directory" else None
        raise write_failed(path, err, step=step, kept=kept) from err
    except foreign as err:  # type: ignore[misc]  # a tuple of exception types
        _remove(tmp)
        raise write_failed(path, err, step=step) from err
    finally:
        _remove(tmp)
    return path


def _remove(tmp: str | None) -> None:
    if tmp is not None and os.path.lexists(tmp):
        with contextlib.suppress(OSError):
            os.unlink(tmp)


@contextlib.contextmanager
def all_or_none(*paths: str | os.PathLike) -> Iterator[None]:
    """Outputs written together (a command's files): when the block raises — a full disk met
    by the third of three files — each of ``paths`` that did not exist when the block began
    is removed, so that a rerun finds none of this run's files and need not ``--force``.
    Files that existed before are left as the block left them (replaced whole, or not)."""
    paths = tuple(os.fspath(p) for p in paths)
    existed = {p for p in paths if os.path.lexists(p)}
    try:
        yield
    except BaseException:
        for p in paths:
            if p not in existed:
                with contextlib.suppress(OSError):
                    os.unlink(p)
        raise


def _lock_paths(target: str) -> tuple[str, str]:
    """(lock file, holder record) of ``target``: inside a directory, beside a file."""
    if os.path.isdir(target):
        base = os.path.join(target, ".brdfscale.lock")
    else:
        directory, name = os.path.split(os.path.abspath(target))
        base = os.path.join(directory, f".{name}.brdfscale.lock")
    return base, base + ".holder.json"


def _holder_text(record: str) -> str:
    try:
        with open(record) as f:
            h = json.load(f)
        return f"process {int(h['pid'])} on {h['host']}, started {h['started']}" + (
            f" ({h['command']})" if h.get("command") else ""
        )
    except (OSError, ValueError, KeyError, TypeError):
        return "another process (its record is missing or unreadable)"


@contextlib.contextmanager
def exclusive(target: str | os.PathLike, *, what: str = "output") -> Iterator[str]:
    """Hold an OS-level lock on ``target`` (an output directory or a file such as a
    checkpoint) for the duration of the ``with`` block.

    A second run — another process, on this host or on another one sharing the file system
    where it supports locks — asking for the same ``target`` gets :class:`OutputInUseError`
    at once, naming the holder (PID, host, start time, command). The lock is the operating
    system's (``filelock``: ``flock`` on POSIX): a killed run's lock disappears with its
    process, so a stale lock is taken over by the next run (its holder record is
    replaced). Re-entrant within a process: a function that locks its output may be called
    inside a run that already holds that lock.

    The lock lives in a hidden file, ``DIR/.brdfscale.lock`` for a directory and
    ``.NAME.brdfscale.lock`` beside a file, with a ``.holder.json`` record beside it.
    """
    import filelock

    target = os.path.abspath(os.fspath(target))
    lock_path, record = _lock_paths(target)
    lock = filelock.FileLock(lock_path, is_singleton=True, thread_local=False)
    try:
        lock.acquire(timeout=0)
    except filelock.Timeout:
        raise OutputInUseError(
            f"{target}: another run is writing this {what}: {_holder_text(record)}. Wait for it to finish, "
            "or choose another output location; two runs into one place would interleave their results."
        ) from None
    except OSError as err:
        raise OutputInUseError(f"{target}: cannot take the lock {lock_path}: {err.strerror or err}.") from err
    try:
        if lock.lock_counter == 1:
            holder = {
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                "command": " ".join(sys.argv[:1] + sys.argv[1:])[:500],
            }

            with contextlib.suppress(OSError, OutputWriteError):  # the record only informs; the lock is the OS's
                write_text(record, json.dumps(holder), overwrite=True, error=OutputInUseError)
        yield target
    finally:
        if lock.lock_counter == 1:  # the outermost holder: the record goes with the lock
            with contextlib.suppress(OSError):
                os.unlink(record)
        lock.release()
