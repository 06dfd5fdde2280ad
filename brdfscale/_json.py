"""JSON for every document brdfscale writes (fit.json, library.json, statistics.json, metadata):
one encoder.

* :func:`jsonable` — a JSON-ready copy of a value: dict keys as text; tuples, lists and arrays
  as lists; NumPy (and JAX) scalars as Python numbers and bools; floats that are not finite
  (NaN, ±∞) as ``None`` — JSON has neither, and in every brdfscale document a non-finite
  figure means "not available" (``null``); dates and times as ISO text. Anything else raises
  ``TypeError``, or becomes ``other(value)`` when ``other`` is given (metadata read from
  instruments' files: ``other=str``).
* :func:`json_text` — ``json.dumps(jsonable(value), allow_nan=False, **options)``.

NumPy is not imported (arrays and scalars are recognised by their ``dtype`` and ``tolist``),
so the command's JAX-free paths can use it. Tested in tests/test_json.py.
"""

import json
import math
import numbers


__all__ = ["json_text", "jsonable"]


def jsonable(value, *, other=None):
    """A JSON-ready copy of ``value`` (module docstring)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): jsonable(v, other=other) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v, other=other) for v in value]
    if getattr(value, "dtype", None) is not None and callable(getattr(value, "tolist", None)):
        return jsonable(value.tolist(), other=other)  # NumPy/JAX scalars and arrays
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return jsonable(float(value))
    if callable(getattr(value, "isoformat", None)):
        return value.isoformat()
    if other is not None:
        return other(value)
    raise TypeError(f"{type(value).__name__} is not a JSON value (str, numbers, bools, None, lists, dicts)")


def json_text(value, *, other=None, **options) -> str:
    """The JSON text of :func:`jsonable` ``(value)`` (``options`` as for ``json.dumps``: ``indent``, …)."""
    return json.dumps(jsonable(value, other=other), allow_nan=False, **options)
