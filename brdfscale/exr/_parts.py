"""Building and reading the parts common to measurement sets and lobe tables."""

import json

import numpy as np
import OpenEXR

from .._errors import InvalidInputError
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


def part_header(kind: str, index: int, count: int, mu: float, extent: float, channels: dict, display: int) -> dict:
    """Header of one part; ``display`` is the largest image side in the file (OpenEXR wants
    one display window for all parts; each part's data window is its own ``n × n``)."""
    return {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "displayWindow": (np.array([0, 0], np.int32), np.array([display - 1, display - 1], np.int32)),
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
