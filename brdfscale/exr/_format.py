"""The on-disk layout shared by measurement sets and lobe tables (docs/conventions.md §6).

One multi-part scanline OpenEXR file; one part per image, all parts ``n × n`` pixels with
the same display window. Pixel ``[j, k]`` of a part (row j from the top of the file) is
the node ``u = (x_k, y_j)`` with ``x, y = linspace(−extent, extent, n)``: row 0 is
``u_y = −extent`` (an image viewer shows +u_y downwards), the layout of
:class:`brdfscale.stats.Tabulated`.

Channels: ``Y``, or ``R``, ``G``, ``B`` — the values; optionally ``sigma`` (or ``sigma.R``,
``sigma.G``, ``sigma.B``) — per-pixel standard deviations; optionally ``mask`` — uint32,
1 where the pixel is valid, 0 elsewhere. Values and σ are float32 or float16.

Header attributes of every part (OpenEXR 3.5 keeps a 1-element float64 array as a double
and a float64 3-vector as a V3d; a Python float would be cut to 32 bits, docs/dependencies.md):

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
``brdfscale.header_digest`` string   sha256 of every other ``brdfscale.*`` attribute and of
                                     the channel list with each channel's type and shape
========================== ========= ===================================================

Integrity (layout version 2): the checksums cover the pixels, the header digest everything
that gives them their meaning — μ, extent, incident direction, domain, kind, version, part
numbering, metadata, the checksums themselves, which channels exist and their pixel types.
Every channel must be listed in the checksums and every listed channel must exist, so a file
rewritten without its ``sigma`` or ``mask`` channel is refused. Files of layout version 1
(no digest) stay readable with a :class:`brdfscale.UnprotectedHeaderWarning`.

Limits of the reader (so that a damaged file can never exhaust memory or the stack): a part
side of at most :data:`MAX_SIDE` pixels, decoded pixels of at most :data:`MAX_EXPANSION`
times the file size (zlib's limit is about 1032), JSON attributes of at most
:data:`MAX_JSON_BYTES` bytes nested at most :data:`MAX_JSON_DEPTH` deep; the writers refuse
metadata beyond the same limits, so whatever they write can be read.
"""

import hashlib
import json
import math
import warnings

import numpy as np

from .._errors import MeasurementFileError, UnprotectedHeaderWarning


FORMAT = "brdfscale"
FORMAT_VERSION = 2
#: Layout versions this reader accepts (1: no header digest, read with a warning).
READABLE_VERSIONS = (1, 2)
DIGEST = "header_digest"
MAX_SIDE = 32768
MAX_EXPANSION = 1100
MAX_JSON_BYTES = 16 * 2**20
MAX_JSON_DEPTH = 64
DOMAIN = "half_slope"
PREFIX = "brdfscale."
VALUE_DTYPES = {"float32": np.float32, "float16": np.float16}


def checksum(pixels: np.ndarray) -> str:
    """sha256 of the pixels as stored (little-endian, row-major)."""
    a = np.ascontiguousarray(pixels)
    return hashlib.sha256(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()).hexdigest()


def header_digest(header: dict, channels: dict) -> str:
    """sha256 over every ``brdfscale.*`` attribute but the digest itself (name, type, value as
    stored: strings as UTF-8, ints in decimal, doubles as their little-endian bytes) and over
    the channels (name, pixel type, shape), in sorted order.

    ``channels`` maps a channel name to its pixel array (or anything with ``dtype`` and
    ``shape``). Raises MeasurementFileError for an attribute of a type brdfscale never writes.
    """
    h = hashlib.sha256()

    def item(*fields):
        for f in fields:
            b = f if isinstance(f, bytes) else str(f).encode("utf-8", "surrogatepass")
            h.update(len(b).to_bytes(8, "little") + b)

    for key in sorted(k for k in header if k.startswith(PREFIX) and k != PREFIX + DIGEST):
        value = header[key]
        if isinstance(value, str):
            item(key, "str", value)
        elif isinstance(value, int) and not isinstance(value, bool):
            item(key, "int", value)
        elif isinstance(value, np.ndarray) and value.dtype == np.float64:
            item(key, "f8", value.shape, value.astype("<f8").tobytes())
        else:
            raise MeasurementFileError(
                f"attribute {key!r} has type {type(value).__name__}, which brdfscale never writes."
            )
    for name in sorted(channels):
        a = channels[name]
        item("channel", name, np.dtype(a.dtype).str, tuple(a.shape))
    return h.hexdigest()


def json_depth(value) -> int:
    """Nesting depth of a JSON value (0 for a scalar), without recursion."""
    depth, stack = 0, [(value, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = list(v.values())
        if isinstance(v, (list, tuple)):
            depth = max(depth, d)
            stack.extend((x, d + 1) for x in v)
    return depth


def json_limit_problem(text: str, value) -> str | None:
    """What breaks the JSON size and depth limits, or None: the one check, for the writers
    (which refuse such metadata) and the reader."""
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_JSON_BYTES:
        return f"{size} bytes of JSON; at most {MAX_JSON_BYTES} are accepted"
    depth = json_depth(value)
    if depth > MAX_JSON_DEPTH:
        return f"JSON nested {depth} deep; at most {MAX_JSON_DEPTH} levels are accepted"
    return None


def _show(value) -> str:
    """repr for messages, safe for damaged attributes (whose repr can itself fail) and short."""
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001 — an undecodable attribute of the bindings
        return f"<undecodable {type(value).__name__}>"
    return text if len(text) <= 120 else text[:117] + "..."


def _no_constant(name):
    raise ValueError(f"{name} is not valid JSON (brdfscale writes finite numbers only)")


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
            self.fail(f"attribute {PREFIX + key!r}", f"must be {expected!r}; got {_show(value)}.")
        return value

    def integer(self, key: str) -> int:
        value = self.attribute(key)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(f"attribute {PREFIX + key!r}", f"must be an int; got {type(value).__name__} {_show(value)}.")
        return value

    def positive_double(self, key: str) -> float:
        value = self.attribute(key)
        a = np.asarray(value)
        if not (isinstance(value, np.ndarray) and a.dtype == np.float64 and a.shape == (1,)):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a double (1-element float64); got {_show(value)}.")
        x = float(a[0])
        if not (math.isfinite(x) and x > 0):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a positive finite number; got {x!r}.")
        return x

    def unit_vector(self, key: str) -> np.ndarray:
        value = self.attribute(key)
        a = np.asarray(value)
        if not (isinstance(value, np.ndarray) and a.dtype == np.float64 and a.shape == (3,)):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a V3d (3 doubles); got {_show(value)}.")
        if not (np.all(np.isfinite(a)) and abs(np.linalg.norm(a) - 1) <= 1e-6 and a[2] > 0):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a unit vector with z > 0; got {a.tolist()}.")
        return a.astype(float)

    def json_object(self, key: str) -> dict:
        text = self.string(key)
        what = f"attribute {PREFIX + key!r}"
        if len(text) > MAX_JSON_BYTES:
            self.fail(what, f"holds {len(text)} characters; at most {MAX_JSON_BYTES} bytes of JSON are accepted.")
        try:
            value = json.loads(text, parse_constant=_no_constant)
        except RecursionError:
            self.fail(what, f"JSON nested too deep; at most {MAX_JSON_DEPTH} levels are accepted.")
        except ValueError as err:  # JSONDecodeError, NaN/Infinity, an integer beyond Python's digit limit
            self.fail(what, f"is not valid JSON ({err}).")
        problem = json_limit_problem(text, value)
        if problem:
            self.fail(what, problem + ".")
        if not isinstance(value, dict):
            self.fail(f"attribute {PREFIX + key!r}", f"must be a JSON object; got {type(value).__name__}.")
        return value

    def common(self, kind: str, count: int) -> None:
        """Check the attributes every part carries (format, version, kind, index, count, domain)."""
        self.string("format", FORMAT)
        version = self.integer("version")
        if version not in READABLE_VERSIONS:
            self.fail(
                f"attribute {PREFIX + 'version'!r}",
                f"layout version {version} is not supported (this reader: {', '.join(map(str, READABLE_VERSIONS))}).",
            )
        self.version = version
        self.string("kind", kind)
        if self.integer("part_index") != self.index:
            self.fail(
                f"attribute {PREFIX + 'part_index'!r}",
                f"is {self.header[PREFIX + 'part_index']}, expected {self.index} (parts out of order).",
            )
        declared = self.integer("part_count")
        if declared != count:
            self.fail(
                f"attribute {PREFIX + 'part_count'!r}",
                f"declares {declared} parts but the file has {count} (truncated or damaged).",
            )
        self.string("domain", DOMAIN)

    def verify_header(self) -> None:
        """The header digest (version 2) and the channel list against the checksums: called by
        the readers after every attribute of the part was checked on its own (whose messages
        are the more specific), so that a change that still looks valid is caught too."""
        version = self.version
        key = PREFIX + DIGEST
        if version == 1:
            if key in self.header:
                self.fail(
                    f"attribute {PREFIX + 'version'!r}",
                    "is 1, but the part carries a header digest, which layout 1 never had (the file is corrupted).",
                )
            if self.index == 0:
                warnings.warn(
                    f"{self.path}: layout version 1: its pixels are checked, but its header attributes (μ, "
                    "extent, incident direction, metadata) are not protected by a digest; read and write it "
                    "again to protect them.",
                    UnprotectedHeaderWarning,
                    stacklevel=4,
                )
        else:
            stored = self.string(DIGEST)
            try:
                computed = header_digest(self.header, {n: c.pixels for n, c in self.channels.items()})
            except MeasurementFileError as err:
                self.fail("header", str(err))
            if computed != stored:
                self.fail(
                    f"attribute {key!r}",
                    "does not match the header (an attribute, the channel list or a "
                    "channel's type was changed after writing: the file is corrupted).",
                )
        listed = set(self.json_object("checksums"))
        present = set(self.channels)
        if listed - present:
            self.fail("channels", f"{sorted(listed - present)} listed in {PREFIX + 'checksums'!r} but missing.")
        if present - listed:
            self.fail("channels", f"{sorted(present - listed)} present but not listed in {PREFIX + 'checksums'!r}.")

    def pixels(self, channel: str, dtypes: tuple) -> np.ndarray:
        """A channel's pixels, checked for dtype, square shape and against the stored checksum."""
        if channel not in self.channels:
            self.fail(f"channel {channel!r}", f"missing (channels present: {sorted(self.channels)}).")
        a = np.asarray(self.channels[channel].pixels)
        if a.dtype not in dtypes:
            self.fail(
                f"channel {channel!r}",
                f"has pixel type {a.dtype}; expected {' or '.join(str(np.dtype(d)) for d in dtypes)}.",
            )
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
