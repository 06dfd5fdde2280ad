"""Measurement sets (:class:`brdfscale.MeasurementSet`) as multi-part OpenEXR files."""

import json

import numpy as np
import OpenEXR

from .._errors import BrdfscaleError, InvalidInputError, MeasurementFileError
from .._measurement import LobeImage, MeasurementSet
from ._format import (
    DOMAIN,
    FLOAT16_MAX,
    FORMAT,
    FORMAT_VERSION,
    PREFIX,
    VALUE_DTYPES,
    PartReader,
    channel_names,
    checksum,
    double,
)
from ._io import open_parts, write_parts

KIND = "measurement_set"


def _store(a: np.ndarray, dtype, what: str) -> np.ndarray:
    if dtype == np.float16 and np.max(np.abs(a), initial=0) > FLOAT16_MAX:
        raise InvalidInputError(f"{what} exceeds the float16 range (±{FLOAT16_MAX}); write with dtype='float32'.")
    return np.ascontiguousarray(a, dtype=dtype)


def image_channels(values, sigma, mask, dtype, what: str) -> dict:
    """The channel dict of one image (values Y or R,G,B; σ; mask) in the stored dtypes."""
    rgb = values.ndim == 3
    names, sigma_names = channel_names(rgb)
    planes = [values[..., c] for c in range(3)] if rgb else [values]
    channels = {n: _store(p, dtype, f"{what} values") for n, p in zip(names, planes)}
    if sigma is not None:
        for n, p in zip(sigma_names, [sigma[..., c] for c in range(3)] if rgb else [sigma]):
            stored = _store(p, dtype, f"{what} sigma")
            if not np.all(stored > 0):
                raise InvalidInputError(f"{what} sigma underflows to 0 in {np.dtype(dtype)}; write with dtype='float32'.")
            channels[n] = stored
    if mask is not None:
        channels["mask"] = np.ascontiguousarray(mask, dtype=np.uint32)
    return channels


def part_header(kind: str, index: int, count: int, mu: float, extent: float, channels: dict, n: int) -> dict:
    return {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "displayWindow": (np.array([0, 0], np.int32), np.array([n - 1, n - 1], np.int32)),
        PREFIX + "format": FORMAT,
        PREFIX + "version": FORMAT_VERSION,
        PREFIX + "kind": kind,
        PREFIX + "part_index": index,
        PREFIX + "part_count": count,
        PREFIX + "mu": double(mu),
        PREFIX + "extent": double(extent),
        PREFIX + "domain": DOMAIN,
        PREFIX + "checksums": json.dumps({name: checksum(p) for name, p in channels.items()}, sort_keys=True),
    }


def metadata_json(metadata: dict) -> str:
    try:
        return json.dumps(metadata, allow_nan=False, sort_keys=True)
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"metadata must be JSON-serialisable (finite numbers, str, lists, dicts): {err}") from err


def check_dtype(dtype: str):
    if dtype not in VALUE_DTYPES:
        raise InvalidInputError(f"dtype must be 'float32' or 'float16'; got {dtype!r}.")
    return VALUE_DTYPES[dtype]


def write_measurements(path, mset: MeasurementSet, *, overwrite: bool = False, dtype: str = "float32") -> None:
    """Write a measurement set as a multi-part OpenEXR file (layout: :mod:`brdfscale.exr`).

    One part per :class:`LobeImage`, in order; values and σ stored as ``dtype``
    (``"float32"`` or ``"float16"``: about 3 significant digits, |x| ≤ 65504), μ, the
    extent and the incident direction as doubles, ``mset.metadata`` as JSON in part 0.
    The write is atomic; an existing ``path`` is replaced only with ``overwrite=True``.

    Raises:
        InvalidInputError: not a MeasurementSet, metadata not JSON-serialisable, or values
            outside the float16 range.
        MeasurementFileError: ``path`` exists (and not ``overwrite``), or cannot be written.
    """
    if not isinstance(mset, MeasurementSet):
        raise InvalidInputError(f"mset must be a brdfscale.MeasurementSet; got {type(mset).__name__}.")
    stored = check_dtype(dtype)
    meta = metadata_json(mset.metadata)
    parts = []
    for index, image in enumerate(mset.images):
        what = f"image {index}"
        channels = image_channels(image.values, image.sigma, image.mask, stored, what)
        header = part_header(KIND, index, len(mset.images), image.mu, image.extent, channels, image.size)
        header[PREFIX + "incident"] = np.asarray(image.incident, dtype=np.float64)
        if index == 0:
            header[PREFIX + "metadata"] = meta
        parts.append(OpenEXR.Part(header, channels, name=f"lobe{index:04d}"))
    write_parts(path, parts, overwrite)


def read_image_part(part: PartReader):
    """Values, σ and mask of a part, with its channel set checked."""
    rgb = "R" in part.channels or "G" in part.channels or "B" in part.channels
    names, sigma_names = channel_names(rgb)
    if rgb and "Y" in part.channels:
        part.fail("channels", "has both Y and R/G/B; expected one or the other.")
    part.check_channels(set(names) | set(sigma_names) | {"mask"})
    values = part.values(names)
    sigma = None
    if any(c in part.channels for c in sigma_names):
        sigma = part.values(sigma_names)
        if not np.all(sigma > 0):
            part.fail(f"channel(s) {', '.join(sigma_names)}", "must be positive standard deviations.")
    mask = None
    if "mask" in part.channels:
        m = part.pixels("mask", (np.uint32,))
        if not np.all((m == 0) | (m == 1)):
            part.fail("channel 'mask'", "must hold only 0 (invalid) and 1 (valid).")
        mask = m.astype(bool)
    for what, a in (("sigma", sigma), ("mask", mask)):
        if a is not None and a.shape[:2] != values.shape[:2]:
            part.fail(f"channel {what!r}", f"shape {a.shape[:2]} differs from the values' {values.shape[:2]}.")
    return values, sigma, mask


def read_measurements(path) -> MeasurementSet:
    """Read a measurement set written by :func:`write_measurements`; validate everything.

    Values and σ come back as float64 arrays (exactly the stored float32/float16 numbers),
    μ, extent and incident directions as the doubles written.

    Raises:
        MeasurementFileError: missing, unreadable, truncated or corrupted file (checksum
            mismatch), wrong or missing attribute or channel, not a measurement set. The
            message names the file, the part and the attribute or channel.
    """
    parts = open_parts(path)
    images, metadata = [], {}
    for index, raw in enumerate(parts):
        part = PartReader(path, index, raw)
        part.common(KIND, len(parts))
        mu = part.positive_double("mu")
        extent = part.positive_double("extent")
        incident = part.unit_vector("incident")
        values, sigma, mask = read_image_part(part)
        if index == 0:
            metadata = part.json_object("metadata")
        try:
            images.append(LobeImage(mu=mu, incident=incident, extent=extent, values=values, sigma=sigma, mask=mask))
        except BrdfscaleError as err:
            part.fail("image", str(err))
    try:
        return MeasurementSet(tuple(images), metadata)
    except BrdfscaleError as err:
        raise MeasurementFileError(f"{path}: {err}") from err


def file_kind(path) -> str:
    """``"measurement_set"`` or ``"lobe_table"``: the ``brdfscale.kind`` of part 0 (validated)."""
    parts = open_parts(path)
    part = PartReader(path, 0, parts[0])
    part.string("format", FORMAT)
    kind = part.string("kind")
    if kind not in (KIND, "lobe_table"):
        part.fail(f"attribute {PREFIX + 'kind'!r}", f"must be 'measurement_set' or 'lobe_table'; got {kind!r}.")
    return kind
