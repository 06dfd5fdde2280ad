"""Measurement sets (:class:`brdfscale.MeasurementSet`) as multi-part OpenEXR files."""

import numpy as np

from .._errors import BrdfscaleError, InvalidInputError, MeasurementFileError
from .._files import file_path
from .._measurement import LobeImage, MeasurementSet
from .._validation import flag
from ._format import FORMAT, PartReader, PREFIX
from ._io import open_parts, write_parts
from ._parts import check_dtype, image_channels, metadata_json, part_header, read_image_part, sealed_part


KIND = "measurement_set"


def write_measurements(path, mset: MeasurementSet, *, overwrite: bool = False, dtype: str = "float32") -> None:
    """Write a measurement set as a multi-part OpenEXR file (layout: :mod:`brdfscale.exr`).

    One part per :class:`LobeImage`, in order; values and σ stored as ``dtype``
    (``"float32"``: |x| ≤ 3.4e38, or ``"float16"``: about 3 significant digits,
    |x| ≤ 65504, nonzero |x| ≥ 6e-8), μ, the extent and the incident direction as doubles,
    ``mset.metadata`` as JSON in part 0. Nothing is lost beyond rounding: an entry that the
    cast would turn into inf, a σ that it would turn into 0, or a value that it would turn
    into 0 although it is not negligible against the largest of its channel (beyond the
    dtype's precision) is refused. The write is atomic; an existing ``path`` is replaced
    only with ``overwrite=True``.

    Raises:
        InvalidInputError: ``path`` not a str or os.PathLike, not a MeasurementSet,
            metadata not a dict with str keys and JSON-serialisable values, a bad ``dtype``
            or ``overwrite``, or values or σ that do not fit ``dtype`` (as above).
        MeasurementFileError: ``path`` exists (and not ``overwrite``), is a directory, or
            cannot be written.
    """
    path = file_path(path, "an .exr file")
    overwrite = flag(overwrite, "overwrite")
    if not isinstance(mset, MeasurementSet):
        raise InvalidInputError(f"mset must be a brdfscale.MeasurementSet; got {type(mset).__name__}.")
    stored = check_dtype(dtype)
    meta = metadata_json(mset.metadata)
    parts = []
    display = max(image.size for image in mset.images)
    for index, image in enumerate(mset.images):
        what = f"image {index}"
        channels = image_channels(image.values, image.sigma, image.mask, stored, what)
        header = part_header(KIND, index, len(mset.images), image.mu, image.extent, channels, display)
        header[PREFIX + "incident"] = np.asarray(image.incident, dtype=np.float64)
        if index == 0:
            header[PREFIX + "metadata"] = meta
        parts.append(sealed_part(header, channels, f"lobe{index:04d}"))
    write_parts(path, parts, overwrite)


def read_measurements(path) -> MeasurementSet:
    """Read a measurement set written by :func:`write_measurements`; validate everything.

    Values and σ come back as float64 arrays (exactly the stored float32/float16 numbers),
    μ, extent and incident directions as the doubles written.

    Raises:
        InvalidInputError: ``path`` not a str or os.PathLike.
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
        part.verify_header()
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
