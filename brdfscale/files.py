"""Files that brdfscale and its users' runs write: atomic, no-clobber, exclusive.

* :func:`atomic_write` — a file appears whole or not at all, and an existing one is replaced
  only when asked; temporary files of a killed write are removed by the next write;
* :func:`write_bytes`, :func:`write_text` — the same for data in hand, checking every byte;
  every write is flushed, fsynced, checked and closed before it is moved into place, and any
  operating-system error (a full disk above all) is :class:`brdfscale.OutputWriteError`
  naming the file and the free space; :func:`require_free_space` refuses a large write
  before it starts, :func:`free_space` says what is left, and :func:`write_failed` makes
  the same error for a writer that cannot go through :func:`atomic_write` (HDF5 in place);
  :func:`all_or_none` removes a command's new files when one of them could not be written;
* :func:`exclusive` — an OS-level lock on an output directory or checkpoint, refusing a
  second run at once with the holder named (:class:`brdfscale.OutputInUseError`);
* :func:`jsonable`, :func:`json_text` — the one JSON encoder of the documents brdfscale writes
  (non-finite numbers as ``null``, NumPy scalars and arrays as Python numbers and lists).
"""

from ._files import (
    all_or_none,
    atomic_write,
    exclusive,
    free_space,
    require_free_space,
    write_bytes,
    write_failed,
    write_text,
)
from ._json import json_text, jsonable


__all__ = [
    "all_or_none",
    "atomic_write",
    "exclusive",
    "free_space",
    "json_text",
    "jsonable",
    "require_free_space",
    "write_bytes",
    "write_failed",
    "write_text",
]
