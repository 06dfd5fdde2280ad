"""File access: atomic, no-clobber writes and checked opening."""

import os

import OpenEXR

from .._errors import InvalidInputError, MeasurementFileError
from .._files import atomic_write
from .._validation import flag
from ._format import PREFIX


def file_path(path) -> str:
    """``path`` as a str, or InvalidInputError when it cannot name a file."""
    try:
        p = os.fspath(path)
    except TypeError:
        raise InvalidInputError(
            f"path must be a str or os.PathLike naming an .exr file; got {type(path).__name__} {path!r}."
        ) from None
    if isinstance(p, bytes):
        p = os.fsdecode(p)
    if not p or "\0" in p:
        raise InvalidInputError(f"path must be a non-empty file name without NUL characters; got {p!r}.")
    return p


def write_parts(path, parts: list, overwrite: bool) -> None:
    """Write ``OpenEXR.Part``s to ``path`` atomically, never replacing a file unless
    ``overwrite`` (see :func:`brdfscale._files.atomic_write`).

    Raises InvalidInputError for a ``path`` that is no file name, MeasurementFileError
    naming the path when it is a directory or cannot be written (permissions, full disk, …).
    """
    path = file_path(path)
    overwrite = flag(overwrite, "overwrite")
    if os.path.isdir(path):
        raise MeasurementFileError(f"{path}: is a directory; give the path of an .exr file to write (e.g. inside it).")

    def write(tmp):
        try:
            OpenEXR.File(parts).write(tmp)
        except (RuntimeError, TypeError, ValueError) as err:
            raise MeasurementFileError(f"{path}: OpenEXR could not write the file: {err}") from err

    try:
        atomic_write(path, write, overwrite=overwrite, error=MeasurementFileError)
    except OSError as err:
        raise MeasurementFileError(f"{path}: cannot write the file: {err.strerror or err}.") from err


def open_parts(path) -> list:
    """Open ``path`` and return its parts, checking that none is missing.

    OpenEXR 3.5 raises for a missing, non-EXR or header-truncated file but only prints a
    warning (to stderr, from C++) and drops the damaged parts when the file is cut inside the
    pixel data (FIELD-NOTES); every part records the part count, so a short file is
    reported here.
    """
    path = file_path(path)
    if os.path.isdir(path):
        raise MeasurementFileError(f"{path}: is a directory, not an .exr file.")
    if not os.path.isfile(path):
        raise MeasurementFileError(f"{path}: no such file.")
    try:
        parts = list(OpenEXR.File(path, separate_channels=True).parts)
    except RuntimeError as err:
        raise MeasurementFileError(f"{path}: not a readable OpenEXR file ({err}).") from err
    if not parts:
        raise MeasurementFileError(f"{path}: no readable part: the file is truncated or its pixel data are damaged.")
    declared = parts[0].header.get(PREFIX + "part_count")
    if isinstance(declared, int) and not isinstance(declared, bool) and declared != len(parts):
        raise MeasurementFileError(
            f"{path}: attribute {PREFIX + 'part_count'!r} of part 0 declares {declared} parts but {len(parts)} "
            "could be read: the file is truncated or damaged."
        )
    return parts
