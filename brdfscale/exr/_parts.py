"""Building and reading the parts common to measurement sets and lobe tables."""

import json

import numpy as np
import OpenEXR

from .._errors import InvalidInputError
from ._format import (
    channel_names,
    checksum,
    DIGEST,
    DOMAIN,
    double,
    FORMAT,
    FORMAT_VERSION,
    header_digest,
    json_limit_problem,
    PartReader,
    PREFIX,
    VALUE_DTYPES,
)


def store(a: np.ndarray, dtype, what: str, *, positive: bool = False) -> np.ndarray:
    """``a`` cast to the stored ``dtype``, refusing what the cast would lose beyond rounding.

    The one check for every float array a writer stores (values, σ, lobe tables), made on
    the cast result itself: a finite entry that becomes ±inf (beyond the dtype's range), or
    a nonzero entry that becomes 0. Zero is a valid value, so for values an entry flushed to
    0 is accepted when it is below the dtype's precision relative to the array's largest
    magnitude (|x| ≤ eps·max|a|: a lobe's far tail); for ``positive`` arrays (σ, which must
    stay > 0) any entry flushed to 0 is refused. Raises InvalidInputError naming ``what``,
    the dtype and its range.
    """
    a = np.asarray(a, dtype=float)
    name = np.dtype(dtype).name
    info = np.finfo(dtype)
    with np.errstate(over="ignore", under="ignore"):
        stored = np.ascontiguousarray(a, dtype=dtype)
    wider = (
        "write with dtype='float32'"
        if name == "float16"
        else "rescale the data (other units) to fit: float32 is the widest float pixel type of OpenEXR"
    )
    over = np.isfinite(a) & ~np.isfinite(stored)
    if np.any(over):
        raise InvalidInputError(
            f"{what}: {np.count_nonzero(over)} entries (largest |x| = {np.max(np.abs(a[over])):.4g}) exceed the "
            f"{name} range (|x| ≤ {float(info.max):.6g}) and would be stored as inf; {wider}."
        )
    lost = (stored == 0) & (a != 0)
    if not positive:
        lost &= np.abs(a) > float(info.eps) * np.max(np.abs(a[np.isfinite(a)]), initial=0)
    if np.any(lost):
        raise InvalidInputError(
            f"{what}: {np.count_nonzero(lost)} nonzero entries (largest |x| = {np.max(np.abs(a[lost])):.4g}) underflow "
            f"to 0 in {name} (smallest nonzero |x|: {float(info.smallest_subnormal):.4g}; normal range from "
            f"{float(info.tiny):.4g}); {wider}."
        )
    return stored


def image_channels(values, sigma, mask, dtype, what: str) -> dict:
    """The channel dict of one image (values Y or R,G,B; σ; mask) in the stored dtypes,
    each float channel checked by :func:`store`."""
    rgb = values.ndim == 3
    names, sigma_names = channel_names(rgb)
    planes = [values[..., c] for c in range(3)] if rgb else [values]
    channels = {n: store(p, dtype, f"{what} values (channel {n})") for n, p in zip(names, planes)}
    if sigma is not None:
        for n, p in zip(sigma_names, [sigma[..., c] for c in range(3)] if rgb else [sigma]):
            channels[n] = store(p, dtype, f"{what} sigma (channel {n})", positive=True)
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


def sealed_part(header: dict, channels: dict, name: str) -> "OpenEXR.Part":
    """The ``OpenEXR.Part`` of a complete header, with its header digest added last (every
    ``brdfscale.*`` attribute must be in ``header`` by now)."""
    header = {**header, PREFIX + DIGEST: header_digest(header, channels)}
    return OpenEXR.Part(header, channels, name=name)


def _string_keys(value, where: str) -> None:
    """JSON turns every key into a string: a non-str key would come back changed."""
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise InvalidInputError(
                    "metadata keys must be strings (JSON stores every key as a string, so it would be read back "
                    f"changed); got {type(key).__name__} key {key!r} in {where}."
                )
            _string_keys(item, f"{where}[{key!r}]")
    elif isinstance(value, (list, tuple)):
        for k, item in enumerate(value):
            _string_keys(item, f"{where}[{k}]")


def metadata_json(metadata) -> str:
    """``metadata`` as the JSON object text stored in part 0; InvalidInputError unless it is a
    dict with str keys and JSON-serialisable values (finite numbers, str, bool, None, lists,
    dicts), so that the reader gets the same object back (tuples come back as lists)."""
    if not isinstance(metadata, dict):
        raise InvalidInputError(
            f"metadata must be a dict (str keys, JSON-serialisable values); got {type(metadata).__name__}."
        )
    try:
        text = json.dumps(metadata, allow_nan=False, sort_keys=True)
    except (TypeError, ValueError, RecursionError) as err:
        try:
            _string_keys(metadata, "metadata")  # the clearer message when mixed keys made sorting fail
        except RecursionError:
            pass
        raise InvalidInputError(
            f"metadata must be JSON-serialisable (finite numbers, str, lists, dicts): {err}"
        ) from err
    _string_keys(metadata, "metadata")  # no cycles: json.dumps would have refused them
    problem = json_limit_problem(text, metadata)
    if problem:
        raise InvalidInputError(f"metadata: {problem} (the reader's limit, so that a damaged file cannot exhaust it).")
    return text


def check_dtype(dtype: str):
    if not isinstance(dtype, str) or dtype not in VALUE_DTYPES:
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
