"""The command line's parser and option types: every value checked against its documented
domain while the command line is parsed, before any work starts.

* :class:`Parser` — ``argparse`` without abbreviations (``--walker`` is not ``--walkers``), and
  every option that does not accumulate by design refused when given twice;
* :func:`integer`, :func:`real`, :func:`seed` — option types with their domain in the message
  (argparse prefixes it with the flag: ``argument --steps: must be an integer in [0, 1000000]``);
* :func:`scales` — facet sizes μ (``--scales`` of ``synth`` and ``topography``): lengths with a
  unit, pixel counts or ``auto[:COUNT]``, parsed here and resolved against the height field by
  :meth:`Scales.resolve` (the one place where a command line's scales become μ);
* :func:`output_file`, :func:`output_directory` — paths checked for writability before the
  work whose result they receive.
"""

import argparse
import dataclasses
import math
import os
import re
from collections.abc import Mapping

from .._errors import InvalidInputError


#: Seeds are 32-bit (numpy's and JAX's generators take them without loss or folding).
MAX_SEED = 2**32 - 1


class _Once(argparse.Action):
    """``store``, refusing a second occurrence (the first value would be lost silently)."""

    def __call__(self, parser, namespace, values, option_string=None):
        _once(parser, namespace, self, option_string)
        setattr(namespace, self.dest, values)


class _OnceTrue(argparse.Action):
    """``store_true``, refusing a second occurrence."""

    def __init__(self, option_strings, dest, default=False, required=False, help=None):
        super().__init__(option_strings, dest, nargs=0, const=True, default=default, required=required, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        _once(parser, namespace, self, option_string)
        setattr(namespace, self.dest, True)


def _once(parser, namespace, action, option_string):
    seen = namespace.__dict__.setdefault("_given", set())
    if action.dest in seen:
        parser.error(
            f"argument {'/'.join(action.option_strings)}: given more than once ({option_string}); give it once."
        )
    seen.add(action.dest)


class Parser(argparse.ArgumentParser):
    """The parser of ``brdfscale`` and of each subcommand (argparse's ``add_parser`` builds
    subparsers of the same class): no abbreviated options, no silently repeated ones."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self.subcommands: Mapping[str, argparse.ArgumentParser] = {}  # name → parser, set by build_parser
        self.register("action", None, _Once)
        self.register("action", "store", _Once)
        self.register("action", "store_true", _OnceTrue)


def _number(text: str, kind):
    try:
        return kind(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(
            f"expected {'an integer' if kind is int else 'a number'}; got {text!r}"
        ) from None


def integer(lo: int, hi: int):
    """An option type: an integer in ``[lo, hi]``."""

    def parse(text: str) -> int:
        value = _number(text, int) if len(text) <= 30 else None
        if value is None or not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be an integer in [{lo}, {hi}]; got {text!r:.40}")
        return value

    parse.__name__ = "integer"
    return parse


def seed(text: str) -> int:
    """An option type: a seed, an integer in [0, 2³² − 1]."""
    return integer(0, MAX_SEED)(text)


def real(lo: float, hi: float, *, strict_lo: bool = False):
    """An option type: a finite number in ``[lo, hi]`` (``(lo, hi]`` with ``strict_lo``)."""

    def parse(text: str) -> float:
        value = _number(text, float)
        if not (math.isfinite(value) and (value > lo if strict_lo else value >= lo) and value <= hi):
            raise argparse.ArgumentTypeError(
                f"must be a finite number in {'(' if strict_lo else '['}{lo:g}, {hi:g}]; got {text!r:.40}"
            )
        return value

    parse.__name__ = "number"
    return parse


def _writable_ancestor(path: str, flag: str) -> None:
    """The nearest existing directory above ``path`` must be writable (it receives ``path``)."""
    parent = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise InvalidInputError(f"{flag} {path}: {parent} is a file, not a directory.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InvalidInputError(f"{flag} {path}: directory {parent} is not writable by this user.")


def output_directory(path: str, flag: str = "--out") -> str:
    """``path`` can be (or already is) a writable directory; InvalidInputError naming ``flag``."""
    if not isinstance(path, str) or not path.strip() or "\0" in path:
        raise InvalidInputError(f"{flag}: give a directory name; got {path!r}.")
    if os.path.exists(path):
        if not os.path.isdir(path):
            raise InvalidInputError(f"{flag} {path}: exists and is not a directory; give a directory for the outputs.")
        if not os.access(path, os.W_OK | os.X_OK):
            raise InvalidInputError(f"{flag} {path}: directory is not writable by this user.")
        return path
    _writable_ancestor(path, flag)
    return path


def output_file(path: str, force: bool, flag: str = "--out") -> str:
    """``path`` can be written (a writable directory exists for it; it is not a directory;
    it does not exist unless ``force``); InvalidInputError naming ``flag`` otherwise."""
    if not isinstance(path, str) or not path.strip() or "\0" in path:
        raise InvalidInputError(f"{flag}: give a file name; got {path!r}.")
    if os.path.isdir(path):
        raise InvalidInputError(f"{flag} {path}: is a directory; give the path of a file to write.")
    if os.path.lexists(path) and not force:
        raise InvalidInputError(f"{flag} {path}: file exists; pass --force to replace it.")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise InvalidInputError(f"{flag} {path}: directory {parent} does not exist.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InvalidInputError(f"{flag} {path}: directory {parent} is not writable by this user.")
    return path


def make_directory(path: str, flag: str = "--out") -> str:
    """Create ``path`` (checked by :func:`output_directory`) and its parents; an OS failure
    (a race, a full disk) as InvalidInputError naming ``flag``."""
    output_directory(path, flag)
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise InvalidInputError(f"{flag} {path}: cannot create the directory: {err.strerror or err}.") from None
    return path


#: At most this many scales on one command line (each is a pass over the height field).
MAX_SCALES = 64

_SCALES_SYNTAX = (
    "1–64 comma-separated scales — lengths with a unit (0.5um, 1e-6m, 0.1mm), whole numbers of "
    "pixels (4px; a bare 4 for a built-in surface) — or auto[:COUNT]"
)
_SCALE_ITEM = re.compile(r"\s*([+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*(\S*)\s*", re.ASCII)


def _length_units() -> dict[str, float]:
    from ..topography import (
        UNITS,  # imports JAX: called only when a command's scales are parsed
    )

    return UNITS


@dataclasses.dataclass(frozen=True)
class Scales:
    """A parsed ``--scales``: ``auto`` with a count, or items ``(value, unit)`` with unit
    ``"px"``, a length unit of :data:`brdfscale.topography.UNITS` or ``""`` (a bare number:
    pixels of a field without a length unit, a built-in surface). :meth:`resolve` turns it
    into facet sizes μ of one height field."""

    text: str
    auto: int | None = None
    items: tuple[tuple[float, str], ...] = ()

    def pixels(self) -> list[float] | None:
        """The scales in pixels when every item is a pixel count (bare or ``px``), else None."""
        if self.auto is not None or any(unit not in ("", "px") for _, unit in self.items):
            return None
        return [value for value, _ in self.items]

    def resolve(self, field, flag: str = "--scales") -> list[float]:
        """Facet sizes μ of ``field`` (a :class:`brdfscale.synth.HeightField`) in its length
        unit, each exactly ``block × Δx``: ``auto`` is ``field.scales(COUNT)``; ``Npx`` is N pixels
        along x; a length is converted to the field's unit. InvalidInputError naming ``flag``
        for a length on a field without a unit (a built-in surface: pixels), a bare number on a
        field with one, a scale that is not a whole number of pixels along both axes or larger
        than the field, or the same scale twice."""
        if self.auto is not None:
            return list(field.scales(self.auto))
        dx = field.spacing[0]
        units = _length_units() if any(unit not in ("", "px") for _, unit in self.items) else {}
        resolved, seen = [], {}
        for (value, unit), item in zip(self.items, self._item_texts()):
            if unit == "px" or (unit == "" and field.unit is None):
                mu, shown = value * dx, f"{value:g} pixel{'s' if value > 1 else ''}"
            elif unit == "":
                raise InvalidInputError(
                    f"{flag} {item}: a bare number is ambiguous for a field measured in {field.unit}; give each scale "
                    f"with its unit (e.g. 0.5um, 2e-6m) or in pixels (e.g. 4px), or auto[:COUNT]."
                )
            elif field.unit is None:
                raise InvalidInputError(
                    f"{flag} {item}: this surface's lengths are in pixels (it has no length unit); give whole numbers "
                    "of pixels (e.g. 4,16,64 or 4px,16px,64px)."
                )
            elif field.unit not in units:
                raise InvalidInputError(
                    f"{flag} {item}: the field's unit {field.unit!r} is not one of "
                    f"{', '.join(units)}; give the scales in pixels (e.g. 4px)."
                )
            else:
                mu = value * units[unit] / units[field.unit]
                shown = f"{mu:.6g} {field.unit} = {mu / dx:.6g} pixels of Δx = {dx:.6g} {field.unit}"
            try:
                rows, cols = field.block(mu)
            except InvalidInputError:
                fy, fx = field.facet_grid
                raise InvalidInputError(
                    f"{flag} {item}: {shown}; a scale must be a whole number of pixels along both axes, from 1 to "
                    f"{min(fx, round(fy * field.spacing[1] / dx))} (the field's {fy} × {fx} pixel facets); "
                    "--scales auto lists admissible ones."
                ) from None
            mu = cols * dx
            if (rows, cols) in seen:
                raise InvalidInputError(
                    f"{flag}: {seen[rows, cols]} and {item} are the same scale "
                    f"({cols} pixel{'s' if cols > 1 else ''}); give each scale once."
                )
            seen[rows, cols] = item
            resolved.append(mu)
        return resolved

    def _item_texts(self) -> list[str]:
        return [t.strip() for t in self.text.split(",") if t.strip()]

    def __str__(self) -> str:
        return self.text


def scales(text: str) -> Scales:
    """An option type: ``--scales`` (:class:`Scales`) — 1–64 comma-separated lengths with a
    unit of :data:`brdfscale.topography.UNITS` (``0.5um``, ``1e-6m``, ``0.1mm``), whole numbers of
    pixels (``4px``; a bare ``4`` for a surface without a length unit), or ``auto[:COUNT]``
    (COUNT 1–64, default 8: ``field.scales(COUNT)``). Whether each scale is a whole number of
    pixels of the field is checked by :meth:`Scales.resolve`."""
    text = text.strip() if isinstance(text, str) else ""
    head, sep, count = text.partition(":")
    if head == "auto":
        if sep and not (count.isascii() and count.isdigit() and 1 <= int(count) <= MAX_SCALES):
            raise argparse.ArgumentTypeError(f"auto:COUNT needs a whole COUNT from 1 to {MAX_SCALES}; got {text!r:.60}")
        return Scales(text, auto=int(count) if sep else 8)
    items = []
    for part in (t for t in text.split(",") if t.strip()):
        match = _SCALE_ITEM.fullmatch(part)
        value = float(match.group(1)) if match else math.nan
        unit = match.group(2) if match else None
        if unit is None or not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"expected {_SCALES_SYNTAX}; got {text!r:.60}")
        if unit in ("", "px"):
            if not (value >= 1 and value == round(value)):
                raise argparse.ArgumentTypeError(
                    f"pixel counts must be whole numbers of pixels ≥ 1; got {part.strip()!r:.40} in {text!r:.60}"
                )
        elif unit not in _length_units():
            raise argparse.ArgumentTypeError(
                f"unknown unit {unit!r:.20} in {part.strip()!r:.40}: lengths take one of "
                f"{', '.join(_length_units())}, pixel counts px; got {text!r:.60}"
            )
        items.append((value, unit))
    if not 1 <= len(items) <= MAX_SCALES:
        raise argparse.ArgumentTypeError(f"expected {_SCALES_SYNTAX}; got {text!r:.60}")
    return Scales(text, items=tuple(items))
