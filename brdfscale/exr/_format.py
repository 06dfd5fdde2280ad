"""The on-disk layout shared by measurement sets and lobe tables (DESIGN §6).

One multi-part scanline OpenEXR file; one part per image, all parts ``n × n`` pixels with
the same display window. Pixel ``[j, k]`` of a part (row j from the top of the file) is
the node ``u = (x_k, y_j)`` with ``x, y = linspace(−extent, extent, n)``: row 0 is
``u_y = −extent`` (an image viewer shows +u_y downwards), the layout of
:class:`brdfscale.stats.Tabulated`.

Channels: ``Y``, or ``R``, ``G``, ``B`` — the values; optionally ``sigma`` (or ``sigma.R``,
``sigma.G``, ``sigma.B``) — per-pixel standard deviations; optionally ``mask`` — uint32,
1 where the pixel is valid, 0 elsewhere. Values and σ are float32 or float16.

Header attributes of every part (OpenEXR 3.5 keeps a 1-element float64 array as a double
and a float64 3-vector as a V3d; a Python float would be cut to 32 bits, FIELD-NOTES):

========================== ========= ===================================================
``brdfscale.format``       string    ``"brdfscale"``
``brdfscale.version``      int       layout version, :data:`FORMAT_VERSION`
``brdfscale.kind``         string    ``"measurement_set"`` or ``"lobe_table"``
``brdfscale.part_index``   int       0 … part_count − 1, in file order
``brdfscale.part_count``   int       number of parts (detects a file cut short)
``brdfscale.mu``           double    the scale μ (> 0)
``brdfscale.extent``       double    grid half-width a (> 0, slope units)
``brdfscale.domain``       string    ``"half_slope"``: the grid is u = m_s − m∞
``brdfscale.checksums``    string    JSON ``{channel: sha256 hex of its stored pixels}``
``brdfscale.incident``     V3d       measurement sets: unit vector towards the light
``brdfscale.metadata``     string    part 0: JSON object of set-level metadata
========================== ========= ===================================================
"""

import hashlib
import json
import math

import numpy as np

from .._errors import MeasurementFileError

FORMAT = "brdfscale"
FORMAT_VERSION = 1
DOMAIN = "half_slope"
PREFIX = "brdfscale."
VALUE_DTYPES = {"float32": np.float32, "float16": np.float16}


def checksum(pixels: np.ndarray) -> str:
    """sha256 of the pixels as stored (little-endian, row-major)."""
    a = np.ascontiguousarray(pixels)
    return hashlib.sha256(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()).hexdigest()


def double(value: float) -> np.ndarray:
    """A scalar as an attribute that OpenEXR stores as a double."""
    return np.array([float(value)], dtype=np.float64)


def channel_names(rgb: bool) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(value channels, σ channels) for Y or RGB images."""
    if rgb:
        return ("R", "G", "B"), ("sigma.R", "sigma.G", "sigma.B")
    return ("Y",), ("sigma",)


class PartReader:
    """Validated access to one part's header and channels; errors name file, part, attribute."""

    def __init__(self, path, index: int, part):
        self.path = str(path)
        self.index = index
        self.header = part.header
        self.channels = part.channels
        self.name = self.header.get("name", "?")

    def fail(self, what: str, message: str):
        raise MeasurementFileError(f"{self.path}: part {self.index} ({self.name!r}): {what}: {message}")

    def attribute(self, key: str):
        full = PREFIX + key
        if full not in self.header:
            self.fail(f"attribute {full!r}", "missing (not a brdfscale file, or written by another program).")
        return self.header[full]

    def string(self, key: str, expected: str | None = None) -> str:
        value = self.attribute(key)
        if not isinstance(value, str):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a string; got {type(value).__name__}.")
        if expected is not None and value != expected:
            self.fail(f"attribute {PREFIX + key!r}", f"must be {expected!r}; got {value!r}.")
        return value

    def integer(self, key: str) -> int:
        value = self.attribute(key)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(f"attribute {PREFIX + key!r}", f"must be an int; got {type(value).__name__} {value!r}.")
        return value

    def positive_double(self, key: str) -> float:
        value = self.attribute(key)
        a = np.asarray(value)
        if not (isinstance(value, np.ndarray) and a.dtype == np.float64 and a.shape == (1,)):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a double (1-element float64); got {value!r}.")
        x = float(a[0])
        if not (math.isfinite(x) and x > 0):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a positive finite number; got {x!r}.")
        return x

    def unit_vector(self, key: str) -> np.ndarray:
        value = self.attribute(key)
        a = np.asarray(value)
        if not (isinstance(value, np.ndarray) and a.dtype == np.float64 and a.shape == (3,)):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a V3d (3 doubles); got {value!r}.")
        if not (np.all(np.isfinite(a)) and abs(np.linalg.norm(a) - 1) <= 1e-6 and a[2] > 0):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a unit vector with z > 0; got {a.tolist()}.")
        return a.astype(float)

    def json_object(self, key: str) -> dict:
        text = self.string(key)
        try:
            value = json.loads(text)
        except json.JSONDecodeError as err:
            self.fail(f"attribute {PREFIX + key!r}", f"is not valid JSON ({err}).")
        if not isinstance(value, dict):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a JSON object; got {type(value).__name__}.")
        return value

    def common(self, kind: str, count: int) -> None:
        """Check the attributes every part carries (format, version, kind, index, count, domain)."""
        self.string("format", FORMAT)
        version = self.integer("version")
        if version != FORMAT_VERSION:
            self.fail(f"attribute {PREFIX + 'version'!r}", f"layout version {version} is not supported (this reader: {FORMAT_VERSION}).")
        self.string("kind", kind)
        if self.integer("part_index") != self.index:
            self.fail(f"attribute {PREFIX + 'part_index'!r}", f"is {self.header[PREFIX + 'part_index']}, expected {self.index} (parts out of order).")
        declared = self.integer("part_count")
        if declared != count:
            self.fail(f"attribute {PREFIX + 'part_count'!r}", f"declares {declared} parts but the file has {count} (truncated or damaged).")
        self.string("domain", DOMAIN)

    def pixels(self, channel: str, dtypes: tuple) -> np.ndarray:
        """A channel's pixels, checked for dtype, square shape and against the stored checksum."""
        if channel not in self.channels:
            self.fail(f"channel {channel!r}", f"missing (channels present: {sorted(self.channels)}).")
        a = np.asarray(self.channels[channel].pixels)
        if a.dtype not in dtypes:
            self.fail(f"channel {channel!r}", f"has pixel type {a.dtype}; expected {' or '.join(str(np.dtype(d)) for d in dtypes)}.")
        if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] < 2:
            self.fail(f"channel {channel!r}", f"must be square, at least 2×2; got {a.shape}.")
        sums = self.json_object("checksums")
        if channel not in sums:
            self.fail(f"attribute {PREFIX + 'checksums'!r}", f"has no checksum for channel {channel!r}.")
        if checksum(a) != sums[channel]:
            self.fail(f"channel {channel!r}", "pixel data do not match the stored checksum (the file is corrupted).")
        return a

    def values(self, names: tuple[str, ...]) -> np.ndarray:
        """Float channels stacked on a last axis (dropped for a single channel), finite."""
        planes = [self.pixels(c, (np.float16, np.float32)).astype(float) for c in names]
        a = planes[0] if len(planes) == 1 else np.stack(planes, axis=-1)
        if not np.all(np.isfinite(a)):
            self.fail(f"channel(s) {', '.join(names)}", "contain non-finite values.")
        return a

    def check_channels(self, allowed: set[str]) -> None:
        unknown = set(self.channels) - allowed
        if unknown:
            self.fail("channels", f"unexpected channel(s) {sorted(unknown)}; allowed: {sorted(allowed)}.")
