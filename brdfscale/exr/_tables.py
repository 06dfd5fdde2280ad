"""Evolved-BRDF tables: lobes tabulated on a half-slope grid at several scales, as OpenEXR."""

import dataclasses
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from jaxtyping import Float

from .._errors import BrdfscaleError, InvalidInputError, MeasurementFileError
from .._files import file_path
from .._validation import flag, integer, real, real_array
from ..lobes import AbstractLobe
from ._format import PartReader, PREFIX
from ._io import open_parts, write_parts
from ._parts import check_dtype, image_channels, metadata_json, part_header, read_image_part, sealed_part


KIND = "lobe_table"

MAX_TABLE_BYTES = 2**31
"""The most bytes :meth:`LobeTable.from_lobes` may allocate for the table and its offset grid
(``8 · size² · (k + 2)`` for k scales, float64): 2 GiB, e.g. ``size`` up to 9459 for one
scale or 4096 for 14 scales. Larger requests are refused before anything is allocated."""


@dataclasses.dataclass(frozen=True, init=False)
class LobeTable:
    """Lobes ``A·g(u, μ)`` at several scales on one grid of offsets ``u = m_s − m∞``.

    Attributes:
        scales: the scales μ, shape (k,), positive and distinct.
        extent: half-width a of the grid: nodes ``linspace(−a, a, n)`` on both axes
            (rows u_y, columns u_x, as :class:`brdfscale.stats.Tabulated`).
        values: shape (k, n, n) or (k, n, n, 3) (RGB); finite (an evolved lobe may dip below
            zero by quadrature or regularisation error, so the sign is not checked).
        metadata: a dict of extras (how the table was made), str keys and JSON-serialisable
            values (a mapping is copied into a dict; JSON is checked when written).

    The constructor takes any array-like scales and values (lists, NumPy or JAX arrays) and
    any mapping as metadata, and stores them converted as the attributes above (an explicit
    ``__init__``: the attributes' annotations are what is stored, its parameters' what is
    accepted).

    Raises InvalidInputError for scales, extent or values that are not finite real numbers
    (complex, bool, text, None or ragged input is refused, not cast), wrong shapes, or
    scales that are not distinct and positive.
    """

    scales: Float[np.ndarray, " k"]
    extent: float
    values: Float[np.ndarray, "k n n"] | Float[np.ndarray, "k n n 3"]
    metadata: dict

    def __init__(
        self,
        scales: npt.ArrayLike,
        extent: float,
        values: npt.ArrayLike,
        metadata: Mapping[Any, Any] = MappingProxyType({}),  # read-only: a shared default cannot be changed
    ):
        scales = np.atleast_1d(real_array(scales, "scales"))
        if scales.ndim != 1 or not np.all(scales > 0) or len(np.unique(scales)) != len(scales):
            raise InvalidInputError(f"scales must be distinct positive numbers; got {scales!r}.")
        extent = real(extent, "extent", minimum=0, strict=True)
        values = real_array(values, "values")
        ok = values.ndim in (3, 4) and values.shape[0] == len(scales) and values.shape[1] == values.shape[2] >= 2
        if not ok or (values.ndim == 4 and values.shape[3] != 3):
            raise InvalidInputError(
                f"values must have shape (k, n, n) or (k, n, n, 3) with k = {len(scales)} scales, n ≥ 2; "
                f"got {values.shape}."
            )
        if not isinstance(metadata, Mapping):
            raise InvalidInputError(
                f"metadata must be a dict (str keys, JSON-serialisable values); got {type(metadata).__name__}."
            )
        object.__setattr__(self, "scales", scales)
        object.__setattr__(self, "extent", extent)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "metadata", dict(metadata))

    @classmethod
    def from_lobes(
        cls,
        scales: npt.ArrayLike,
        lobes,
        *,
        extent: float,
        size: int = 128,
        metadata: Mapping[Any, Any] | None = None,
    ) -> "LobeTable":
        """Tabulate :mod:`brdfscale.lobes` lobes (e.g. results of :func:`brdfscale.evolve`).

        ``lobes[k].density(u)`` is evaluated on the ``size × size`` grid over
        ``[−extent, extent]²``.

        Memory: the float64 table and the offset grid, ``8 · size² · (k + 2)`` bytes for k
        scales, must not exceed :data:`MAX_TABLE_BYTES` (2**31 bytes, 2 GiB); a larger
        request is refused before anything is allocated — use a smaller ``size`` (a
        coarser grid, or a smaller ``extent`` at the same pitch), or tabulate the scales in
        several tables.

        Raises:
            InvalidInputError: scales not distinct positive numbers, lobes not one
                :mod:`brdfscale.lobes` lobe per scale, ``extent`` not a positive real number,
                ``size`` not an integer ≥ 2 (a float such as 128.0 is refused), the table
                above :data:`MAX_TABLE_BYTES`, or ``metadata`` not a dict.
        """
        scales = np.atleast_1d(real_array(scales, "scales"))
        try:
            lobes = list(lobes)
        except TypeError:
            raise InvalidInputError(
                f"lobes must be a sequence of brdfscale.lobes lobes (one per scale); got {type(lobes).__name__}."
            ) from None
        if not all(isinstance(lobe, AbstractLobe) for lobe in lobes):
            raise InvalidInputError("lobes must be brdfscale.lobes lobes (one per scale).")
        if scales.ndim != 1 or not lobes or len(lobes) != len(scales):
            raise InvalidInputError(
                f"give one lobe per scale; got {len(lobes)} lobes for scales of shape {scales.shape}."
            )
        extent = real(extent, "extent", minimum=0, strict=True)
        size = integer(size, "size", 2)
        needed = 8 * size * size * (len(lobes) + 2)
        if needed > MAX_TABLE_BYTES:
            raise InvalidInputError(
                f"a lobe table of {len(lobes)} scale(s) at size={size} needs about {needed / 2**30:.3g} GiB "
                f"(8 · size² · (scales + 2) bytes), above brdfscale.exr's MAX_TABLE_BYTES = {MAX_TABLE_BYTES} bytes; "
                "use a smaller size (a coarser grid, or a smaller extent at the same pitch) or split the scales "
                "over several tables."
            )
        if metadata is None:
            metadata = {}
        x = jnp.linspace(-extent, extent, size)
        u = jnp.stack(jnp.meshgrid(x, x, indexing="xy"), axis=-1)
        values = None
        for k, lobe in enumerate(lobes):
            plane = np.asarray(lobe.density(u), dtype=float)
            if values is None:
                values = np.empty((len(lobes),) + plane.shape)  # filled in place: no second copy
            elif plane.shape != values.shape[1:]:
                raise InvalidInputError(f"lobe {k} tabulates to shape {plane.shape}, lobe 0 to {values.shape[1:]}.")
            values[k] = plane
        assert values is not None  # lobes is not empty
        return cls(scales, extent, values, metadata)


def write_lobe_table(path, table: LobeTable, *, overwrite: bool = False, dtype: str = "float32") -> None:
    """Write a :class:`LobeTable` as a multi-part OpenEXR file, one part per scale.

    Same layout, checks and guarantees as :func:`write_measurements` (``brdfscale.kind =
    "lobe_table"``, no incident direction, no σ or mask): values that ``dtype`` cannot hold
    (overflow, or underflow to 0 beyond its precision) raise InvalidInputError, a
    directory or unwritable ``path`` MeasurementFileError.
    """
    path = file_path(path, "an .exr file")
    overwrite = flag(overwrite, "overwrite")
    if not isinstance(table, LobeTable):
        raise InvalidInputError(f"table must be a brdfscale.exr.LobeTable; got {type(table).__name__}.")
    stored = check_dtype(dtype)
    meta = metadata_json(table.metadata)
    parts = []
    for index, (mu, values) in enumerate(zip(table.scales, table.values)):
        channels = image_channels(values, None, None, stored, f"scale {index}")
        header = part_header(KIND, index, len(table.scales), mu, table.extent, channels, values.shape[0])
        if index == 0:
            header[PREFIX + "metadata"] = meta
        parts.append(sealed_part(header, channels, f"scale{index:04d}"))
    write_parts(path, parts, overwrite)


def read_lobe_table(path) -> LobeTable:
    """Read a file written by :func:`write_lobe_table`, validating every attribute and channel.

    Raises:
        MeasurementFileError: as :func:`read_measurements`; also when the parts disagree on
            the extent, the grid size or the channels.
    """
    parts = open_parts(path)
    scales, planes, extent, metadata = [], [], None, {}
    for index, raw in enumerate(parts):
        part = PartReader(path, index, raw)
        part.common(KIND, len(parts))
        mu = part.positive_double("mu")
        e = part.positive_double("extent")
        if extent is not None and e != extent:
            part.fail(f"attribute {PREFIX + 'extent'!r}", f"is {e}, but part 0 has {extent}; a table has one grid.")
        extent = e
        values, sigma, mask = read_image_part(part)
        if sigma is not None or mask is not None:
            part.fail("channels", "a lobe table has no sigma or mask channels.")
        if planes and values.shape != planes[0].shape:
            part.fail("channels", f"shape {values.shape} differs from part 0's {planes[0].shape}.")
        if index == 0:
            metadata = part.json_object("metadata")
        part.verify_header()
        scales.append(mu)
        planes.append(values)
    assert extent is not None  # open_parts returns at least one part
    try:
        return LobeTable(np.array(scales), extent, np.stack(planes), metadata)
    except BrdfscaleError as err:
        raise MeasurementFileError(f"{path}: {err}") from err
