"""Atomic, no-clobber file writing and exclusive output locations: the one place where
brdfscale creates files and takes locks (public as :mod:`brdfscale.files`)."""

import contextlib
import datetime
import glob
import json
import os
import socket
import sys
import tempfile
from typing import Callable, Iterator

from ._errors import InvalidInputError, OutputInUseError


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


def atomic_write(
    path: str | os.PathLike,
    write: Callable[[str], None],
    *,
    overwrite: bool = False,
    error: type[Exception] = InvalidInputError,
) -> str:
    """Write ``path`` through ``write(tmp)`` on a temporary file in the same directory.

    Readers never see a half-written file: the temporary file is moved into place only after
    ``write`` returned. Without ``overwrite`` an existing file is never replaced: the
    temporary file is hard-linked to ``path``, which fails if ``path`` exists, even when
    another process creates it meanwhile. The file gets the mode a plain ``open`` would give
    (0666 less the umask). Errors are raised as ``error`` naming the path.

    The temporary file is ``.<name>.brdfscale-<host>-<pid>-<random>.tmp<suffix>``: a process
    killed mid-write (SIGKILL: no ``finally`` runs) leaves it behind, visibly named after its
    target, and the next write to the same ``path`` removes it (tested in
    tests/test_robustness.py).
    """
    path = os.fspath(path)
    if not overwrite and os.path.lexists(path):
        raise error(f"{path}: file exists; pass overwrite=True to replace it.")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise error(f"{path}: directory {directory} does not exist.")
    name = os.path.basename(path)
    _remove_stale_temporaries(directory, name)
    suffix = os.path.splitext(path)[1]
    fd, tmp = tempfile.mkstemp(
        dir=directory, prefix=f".{name}{_TMP_MARK}{_host()}-{os.getpid()}-", suffix=".tmp" + suffix
    )
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        if overwrite:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)
            except FileExistsError:
                raise error(f"{path}: file exists; pass overwrite=True to replace it.") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


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

            def write(tmp):
                with open(tmp, "w") as f:
                    json.dump(holder, f)

            with contextlib.suppress(OSError):  # the record only informs; the lock is the OS's
                atomic_write(record, write, overwrite=True, error=OutputInUseError)
        yield target
    finally:
        if lock.lock_counter == 1:  # the outermost holder: the record goes with the lock
            with contextlib.suppress(OSError):
                os.unlink(record)
        lock.release()
