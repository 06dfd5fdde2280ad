"""Files that brdfscale and its users' runs write: atomic, no-clobber, exclusive.

* :func:`atomic_write` — a file appears whole or not at all, and an existing one is replaced
  only when asked; temporary files of a killed write are removed by the next write;
* :func:`exclusive` — an OS-level lock on an output directory or checkpoint, refusing a
  second run at once with the holder named (:class:`brdfscale.OutputInUseError`);
* :func:`jsonable`, :func:`json_text` — the one JSON encoder of the documents brdfscale writes
  (non-finite numbers as ``null``, NumPy scalars and arrays as Python numbers and lists).
"""

from ._files import atomic_write, exclusive
from ._json import json_text, jsonable


__all__ = ["atomic_write", "exclusive", "json_text", "jsonable"]
