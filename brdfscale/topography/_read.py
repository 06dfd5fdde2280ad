"""Instrument files through SurfaceTopography (the optional extra ``brdfscale[topography]``)."""

import contextlib
import dataclasses
import logging
import math
import os
import re
import warnings
from typing import NoReturn

import numpy as np

from .._errors import BrdfscaleError, InvalidInputError, MeasurementFileError, MissingDependencyError
from .._json import jsonable
from ._array import check_mode, from_array, is_length_unit, UNITS


def _surface_topography():
    try:
        import SurfaceTopography
    except ImportError as err:
        raise MissingDependencyError(
            "reading instrument files needs SurfaceTopography, the optional extra brdfscale[topography]: "
            'pip install "brdfscale[topography]" (or build the field from your own array with '
            f"brdfscale.topography.from_array); the import failed: {err}"
        ) from None
    return SurfaceTopography


def read(path, *, channel: int | str | None = None, detrend: str | None = "plane", micro=None):
    """Read a measured height map from an instrument file as a :class:`brdfscale.synth.HeightField`.

    The file is opened by SurfaceTopography (AFM: Bruker/Digital Instruments ``.di``,
    Molecular Imaging ``.mi``, Asylum ``.ibw``, Park, NT-MDT…; optical: Veeco/Bruker ``.opd``,
    Sensofar ``.plu``/``.plux``, Zygo, Keyence, Olympus…; profilometers: FRT ``.frt``,
    Mitutoyo…; and text, MATLAB, HDF5 and image formats — its documentation lists them).
    Heights and pitch are converted to metres; rows are y and columns x (SurfaceTopography
    indexes ``[x, y]``: transposed here); pixels the instrument did not measure are masked;
    then :func:`from_array` detrends and records the provenance: the file, its format, the
    instrument, the channel, the units of the file and the trend removed.

    Args:
        path: the instrument file.
        channel: the data channel, by index or name (``None``: the file's default height
            channel). The error for a wrong one lists the file's channels.
        detrend: ``"plane"`` (default), ``"curvature"`` or None (see :func:`from_array`).
        micro: the pixel facets' own lobe (default mirror facets).

    Raises:
        MissingDependencyError: SurfaceTopography is not installed (``brdfscale[topography]``).
        MeasurementFileError: the file is missing, unreadable, of no format SurfaceTopography
            knows, or holds no areal height map with physical sizes (a line scan, a file
            without lateral calibration or without a height unit, no heights at all), or the
            channel asked for is not heights (a phase, a deflection: SurfaceTopography's
            ``is_height_channel`` and ``data_unit``); also where the heights it holds are refused
            by :func:`from_array`.
        InvalidInputError: a bad ``channel``, ``detrend`` or ``micro``.
    """
    st = _surface_topography()
    name = os.fspath(path) if isinstance(path, (str, os.PathLike)) else None
    if name is None:
        raise InvalidInputError(f"path must be a file name (str or os.PathLike); got {type(path).__name__}.")
    mode = check_mode(detrend)  # checked before the file is opened (micro, by HeightField, once it is read)
    if not os.path.isfile(name):
        what = (
            "is a directory"
            if os.path.isdir(name)
            else "does not exist"
            if not os.path.lexists(name)
            else "is not a regular file"
        )
        raise MeasurementFileError(f"{name}: {what}; expected an instrument height map (e.g. .di, .opd, .plu, .frt).")
    with _file_errors(name, st) as warned:
        heights, mask, spacing, unit, description = _decode(st, name, channel)
    try:
        field = from_array(heights, spacing, unit=unit, mask=mask, detrend=mode, description=description)
    except InvalidInputError as err:  # the file's heights or pitch, not the caller's arguments
        raise MeasurementFileError(f"{name}: the height map it holds cannot be used: {err}") from None
    field = field if micro is None else dataclasses.replace(field, micro=micro)  # micro checked by HeightField
    for w in warned:  # read: the reader's warnings, which passed the caller's filters, shown as they came
        warnings.showwarning(w.message, w.category, w.filename, w.lineno, w.file, w.line)
    return field


#: The loggers of SurfaceTopography and the libraries its readers use: what they log while a
#: file is read (e.g. igor2's dump of a damaged header) is kept out of the terminal and, when the
#: file cannot be read, its first line is added to the reason.
_READER_LOGGERS = ("SurfaceTopography", "igor2", "netCDF4", "h5py", "PIL", "tifffile")


def _line(text: str) -> str:
    """What a reader logged or warned, as one line of at most 200 characters."""
    return " ".join(text.split())[:200]


class _Kept(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.lines: list[str] = []

    def emit(self, record):
        with contextlib.suppress(Exception):
            self.lines.append(_line(record.getMessage()))


@contextlib.contextmanager
def _file_errors(name: str, st):
    """The one boundary around SurfaceTopography: any exception of its readers (KeyError,
    dateutil's ParserError, IndexError, struct and zlib errors, MemoryError, …) becomes a
    MeasurementFileError naming the file and the reason; brdfscale's own errors pass. What the
    readers log meanwhile is kept off the terminal (:data:`_READER_LOGGERS`); what they log, and the Python
    warnings the caller's filters let through, joins the reason of a file that cannot be read (its first line).
    Yields the list of those warnings, which :func:`read` shows once the file is read and its heights accepted."""
    kept = _Kept()
    loggers = [logging.getLogger(n) for n in _READER_LOGGERS]
    saved = [(lg.handlers[:], lg.propagate) for lg in loggers]
    for lg in loggers:
        lg.handlers, lg.propagate = [kept], False
    try:
        with warnings.catch_warnings(record=True) as warned:  # e.g. openpyxl's on an image inside a .xlsx
            try:
                yield warned
            finally:
                kept.lines.extend(_line(str(w.message)) for w in warned)
    except BrdfscaleError:
        raise
    except Exception as err:
        logged = f"; it logged: {kept.lines[0]}" if kept.lines else ""
        raise MeasurementFileError(
            f"{name}: SurfaceTopography {st.__version__} cannot read it as a topography ({_reason(err)}{logged}); "
            "check the file is an undamaged instrument height map of a format it supports."
        ) from None
    finally:
        for lg, (handlers, propagate) in zip(loggers, saved):
            lg.handlers, lg.propagate = handlers, propagate


def _decode(st, name: str, channel):
    """The height map of ``name`` through SurfaceTopography: heights and mask rows-y (or None),
    the pitch, the unit and the provenance (every call to SurfaceTopography is here)."""
    reader = st.open_topography(name)
    channels = list(reader.channels)
    if not channels:
        raise MeasurementFileError(f"{name}: the file holds no data channel.")
    index = _channel_index(name, reader, channels, channel)
    info = channels[index]
    if 0 in tuple(info.nb_grid_pts or ()):  # e.g. an empty file, which SurfaceTopography's HGT reader takes as 0 × 0
        shape = " × ".join(map(str, info.nb_grid_pts))
        raise MeasurementFileError(f"{name}: holds no heights ({shape} pixels as {type(reader).__name__} reads it).")
    if info.dim == 1:
        raise MeasurementFileError(f"{name}: channel {index} ({info.name!r}) is a line scan, not an areal height map.")
    if not _holds_heights(info):  # a phase in degrees, a deflection in volts, ('µm', None)
        _not_heights(name, index, info, getattr(info, "data_unit", None), channels)
    if info.physical_sizes is None:  # SurfaceTopography's topography() would ask for them
        raise MeasurementFileError(
            f"{name}: channel {index} ({info.name!r}) records its heights but not their pitch (the file's physical "
            f"size); {_AS_ARRAY}"
        )
    topo = reader.topography(channel_index=index)
    if topo.dim != 2:  # the channel's information said otherwise
        raise MeasurementFileError(
            f"{name}: channel {index} ({info.name!r}) is not an areal height map (it reads as {topo.dim}-D)."
        )
    unit = topo.unit
    if not is_length_unit(unit):
        if unit is None:
            raise MeasurementFileError(
                f"{name}: channel {index} ({info.name!r}) records no unit for its heights; {_AS_ARRAY}"
            )
        _not_heights(name, index, info, unit, channels)
    heights = topo.heights()
    mask = ~np.ma.getmaskarray(heights) if np.ma.isMaskedArray(heights) else None
    heights = np.ma.getdata(heights)
    (nx, ny), (lx, ly) = topo.nb_grid_pts, topo.physical_sizes
    if np.shape(heights) != (nx, ny):
        raise MeasurementFileError(
            f"{name}: the file declares {nx} × {ny} pixels but holds heights of shape {np.shape(heights)}."
        )
    spacing = _pitch(name, lx, nx, ly, ny, unit)
    instrument = (topo.info or {}).get("instrument")
    description = {
        "generator": "brdfscale.topography.read",
        "file": os.path.basename(name),
        "path": os.path.abspath(name),
        "format": reader.format() if callable(getattr(reader, "format", None)) else type(reader).__name__,
        "reader": f"SurfaceTopography {st.__version__} {type(reader).__name__}",
        "instrument": jsonable(instrument, other=str),  # JSON-ready: dates as ISO text, other objects as str
        "channel": {"index": index, "name": info.name},
        "file_unit": topo.unit,
        "acquisition_time": jsonable((topo.info or {}).get("acquisition_time"), other=str),
    }
    return heights.T, None if mask is None else mask.T, spacing, unit, description


def _holds_heights(info) -> bool:
    """Whether SurfaceTopography reads a channel as heights (``is_height_channel``) in a length unit brdfscale
    knows — its judgement, which counts an AFM's amplitude in metres as heights."""
    unit = getattr(info, "data_unit", None)
    return bool(getattr(info, "is_height_channel", True)) and (unit is None or is_length_unit(unit))


def _not_heights(name: str, index: int, info, unit, channels) -> NoReturn:
    """The refusal of a channel that does not hold heights, naming the channels that SurfaceTopography reads as
    heights."""
    others = ", ".join(f"{i}: {c.name!r}" for i, c in enumerate(channels) if i != index and _holds_heights(c))
    if not getattr(info, "is_height_channel", True):
        kind = getattr(getattr(info, "data_kind", None), "value", None) or "other"
        what = f"holds {kind} data ({unit!r}), not heights (SurfaceTopography: not a height channel)"
    else:
        what = f"holds {unit!r}, not heights in a length unit brdfscale knows ({', '.join(UNITS)})"
    choose = f"; choose a channel SurfaceTopography reads as heights with channel= among {others}." if others else "."
    raise MeasurementFileError(f"{name}: channel {index} ({info.name!r}) {what}{choose}")


def _pitch(name: str, lx, nx, ly, ny, unit: str) -> tuple[float, float]:
    """The pitch ``(lx/nx, ly/ny)`` in ``unit``; MeasurementFileError for sizes that are not
    positive finite numbers (the range of a physical pitch is checked by :func:`from_array`)."""
    pitches = []
    for axis, length, count in (("x", lx, nx), ("y", ly, ny)):
        value = float(length) / float(count) if float(count) > 0 else math.nan
        if not (math.isfinite(value) and value > 0):
            raise MeasurementFileError(
                f"{name}: the physical size along {axis}, {length!r} {unit} over {count!r} pixels, is not a positive "
                "finite pitch."
            )
        pitches.append(value)
    return pitches[0], pitches[1]


def _reason(err: Exception) -> str:
    """SurfaceTopography's failure in one line: the readers it tried, or its first line."""
    text = str(err).strip()
    tried = re.findall(r"tried (\w+):", text)
    if tried:
        return f"no reader recognises the format; it tried {len(tried)}: {', '.join(tried)}"
    first = text.splitlines()[0] if text else ""
    return f"{type(err).__name__}: {first[:300]}" if first else type(err).__name__


_AS_ARRAY = (
    "if you know it, pass the heights with their pitch and unit to brdfscale.topography.from_array(heights, "
    "spacing, unit=...) (docs/topography.md, 'Your own array')."
)
"""The way round for a file that records heights without their pitch or unit."""


def _channel_index(name, reader, channels, channel) -> int:
    listing = ", ".join(f"{i}: {c.name!r}" for i, c in enumerate(channels))
    if channel is None:
        default = getattr(reader, "default_channel", None)
        return channels.index(default) if default in channels else 0
    if isinstance(channel, str):
        names = [c.name for c in channels]
        if channel in names:
            return names.index(channel)
        raise InvalidInputError(f"{name} has no channel named {channel!r}; its channels are {listing}.")
    if isinstance(channel, (int, np.integer)) and not isinstance(channel, bool) and 0 <= channel < len(channels):
        return int(channel)
    raise InvalidInputError(
        f"channel must be an index from 0 to {len(channels) - 1} or a name; {name} has {listing}; got {channel!r}."
    )
