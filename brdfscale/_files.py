"""Atomic, no-clobber file writing: the one place where brdfscale creates files."""

import os
import tempfile
from typing import Callable

from ._errors import InvalidInputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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
    """
    path = os.fspath(path)
    if not overwrite and os.path.lexists(path):
        raise error(f"{path}: file exists; pass overwrite=True (CLI: --force) to replace it.")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise error(f"{path}: directory {directory} does not exist.")
    suffix = os.path.splitext(path)[1]
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=".brdfscale-", suffix=".tmp" + suffix)
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
                raise error(f"{path}: file exists; pass overwrite=True (CLI: --force) to replace it.") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path
