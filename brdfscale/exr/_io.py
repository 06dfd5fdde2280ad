"""File access: atomic, no-clobber writes and checked opening."""

import os

import OpenEXR

from .._errors import MeasurementFileError
from .._files import atomic_write
from ._format import PREFIX


def write_parts(path, parts: list, overwrite: bool) -> None:
    """Write ``OpenEXR.Part``s to ``path`` atomically, never replacing a file unless
    ``overwrite`` (see :func:`brdfscale._files.atomic_write`)."""

    def write(tmp):
        try:
            OpenEXR.File(parts).write(tmp)
        except (RuntimeError, TypeError, ValueError) as err:
            raise MeasurementFileError(f"{os.fspath(path)}: OpenEXR could not write the file: {err}") from err

    atomic_write(path, write, overwrite=overwrite, error=MeasurementFileError)


def open_parts(path) -> list:
    """Open ``path`` and return its parts, checking that none is missing.

    OpenEXR 3.5 raises for a missing, non-EXR or header-truncated file but only prints a
    warning (to stderr, from C++) and drops the damaged parts when the file is cut inside the
    pixel data (FIELD-NOTES); every part records the part count, so a short file is
    reported here.
    """
    path = os.fspath(path)
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
