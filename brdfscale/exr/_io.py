"""File access: atomic, no-clobber writes and checked opening."""

import os
import stat

import OpenEXR

from .._errors import MeasurementFileError
from .._files import atomic_write, file_path
from .._validation import flag
from ._diagnostics import captured, pass_on, summary
from ._format import MAX_EXPANSION, MAX_SIDE, PREFIX


def write_parts(path, parts: list, overwrite: bool) -> None:
    """Write ``OpenEXR.Part``s to ``path`` atomically, never replacing a file unless
    ``overwrite`` (see :func:`brdfscale._files.atomic_write`).

    Raises InvalidInputError for a ``path`` that is no file name, MeasurementFileError
    naming the path when it is a directory or OpenEXR refuses the parts, and
    OutputWriteError naming the path and the free space when it cannot be written
    (permissions, full disk, an I/O error — OpenEXR reports these as RuntimeError).
    """
    path = file_path(path, "an .exr file")
    overwrite = flag(overwrite, "overwrite")
    if os.path.isdir(path):
        raise MeasurementFileError(f"{path}: is a directory; give the path of an .exr file to write (e.g. inside it).")

    def write(tmp):
        try:
            with captured() as said:
                OpenEXR.File(parts).write(tmp)
        except (TypeError, ValueError) as err:
            raise MeasurementFileError(
                f"{path}: OpenEXR could not write the file: {err}{summary(said.text, tmp)}"
            ) from err
        pass_on(said.text)

    # OpenEXR's RuntimeError is its I/O failure ("Failed to write pixel data … No space left on device")
    atomic_write(path, write, overwrite=overwrite, error=MeasurementFileError, foreign=(RuntimeError,))


def _check_readable(path: str) -> None:
    """MeasurementFileError naming why ``path`` is no file to read (before OpenEXR opens it:
    a FIFO would block, a device is not a file)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        if os.path.lexists(path):
            raise MeasurementFileError(
                f"{path}: is a symbolic link to {os.readlink(path)!r}, which does not exist."
            ) from None
        raise MeasurementFileError(f"{path}: no such file.") from None
    except OSError as err:
        raise MeasurementFileError(f"{path}: cannot be examined: {err.strerror or err}.") from err
    if stat.S_ISDIR(st.st_mode):
        raise MeasurementFileError(f"{path}: is a directory, not an .exr file.")
    if not stat.S_ISREG(st.st_mode):
        raise MeasurementFileError(f"{path}: is not a regular file (a device, FIFO or socket); give an .exr file.")
    if not os.access(path, os.R_OK):
        raise MeasurementFileError(f"{path}: permission denied: the file exists but this user may not read it.")


def _open(path: str, header_only: bool) -> tuple[list, str]:
    """OpenEXR's parts and what its C++ layer printed meanwhile (captured:
    :mod:`brdfscale.exr._diagnostics`); every failure of the bindings (RuntimeError, a bad
    ``type`` attribute's ValueError, a non-UTF-8 attribute's UnicodeDecodeError, …) as
    MeasurementFileError."""
    try:
        with captured() as said:
            parts = list(OpenEXR.File(path, separate_channels=True, header_only=header_only).parts)
    except MemoryError:
        raise MeasurementFileError(
            f"{path}: not readable: decoding would need more memory than there is "
            "(a damaged header declaring huge images?)."
        ) from None
    except Exception as err:  # noqa: BLE001 — the bindings raise whatever their C++ and pybind11 layers give
        raise MeasurementFileError(
            f"{path}: not a readable OpenEXR file ({type(err).__name__}: {err}){summary(said.text, path)}."
        ) from None
    return parts, said.text


def open_parts(path) -> list:
    """Open ``path`` and return its parts, checking that none is missing.

    OpenEXR 3.5 raises for a missing, non-EXR or header-truncated file but only prints a
    warning (on descriptors 1 and 2, from C++) and drops the damaged parts when the file is cut
    inside the pixel data (docs/dependencies.md); every part records the part count, so a short
    file is reported here, in one line with OpenEXR's first diagnostic (the rest is captured,
    :mod:`brdfscale.exr._diagnostics`; what a successful read printed goes to ``sys.stderr``).
    Headers are read first, and a part whose data window is larger than
    :data:`MAX_SIDE` pixels a side, or whose pixels would decode to more than
    :data:`MAX_EXPANSION` times the file's size, is refused before any pixel is decoded.
    """
    path = file_path(path, "an .exr file")
    _check_readable(path)
    headers, said = _open(path, header_only=True)
    budget = MAX_EXPANSION * os.path.getsize(path) + 2**20
    decoded = 0
    for index, part in enumerate(headers):
        try:
            (x0, y0), (x1, y1) = (tuple(int(v) for v in corner) for corner in part.header["dataWindow"])
            width, height = x1 - x0 + 1, y1 - y0 + 1
            n_channels = len(part.header["channels"])
        except (KeyError, TypeError, ValueError):
            raise MeasurementFileError(f"{path}: part {index}: no valid data window or channel list.") from None
        if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
            raise MeasurementFileError(
                f"{path}: part {index}: data window {width} × {height} pixels; brdfscale reads "
                f"at most {MAX_SIDE} a side (the header is damaged, or not a brdfscale file)."
            )
        decoded += 4 * width * height * n_channels
    if decoded > budget:
        raise MeasurementFileError(
            f"{path}: its headers declare {decoded} bytes of pixels, more than {MAX_EXPANSION} "
            "times the file's size: the headers are damaged."
        )
    parts, said_too = _open(path, header_only=False)
    said += said_too
    if not parts:
        raise MeasurementFileError(
            f"{path}: no readable part: the file is truncated or its pixel data are damaged{summary(said, path)}."
        )
    declared = parts[0].header.get(PREFIX + "part_count")
    if isinstance(declared, int) and not isinstance(declared, bool) and declared != len(parts):
        raise MeasurementFileError(
            f"{path}: attribute {PREFIX + 'part_count'!r} of part 0 declares {declared} parts but {len(parts)} "
            f"could be read: the file is truncated or damaged{summary(said, path)}."
        )
    pass_on(said)
    return parts
