"""OpenEXR's C++ diagnostics, captured so that a damaged file costs one line.

OpenEXR 3.5 and its Python bindings print, around Python's exceptions: the C library's error
handler writes ``<path>: (EXR_ERR_…) …`` on file descriptor 2 (below ``sys.stderr``), and the
bindings write ``Warning: Exception raised reading pixel data for part N …`` through Python's
``sys.stdout`` (a file cut inside its pixel data gives four such lines, and they would land
inside the command line's output, e.g. ``fit-library``'s summary). :func:`captured` points
descriptors 1 and 2 at a temporary file and ``sys.stdout``/``sys.stderr`` at a buffer around
one OpenEXR call and hands back what was written; the caller folds it into its
:class:`~brdfscale.MeasurementFileError` (:func:`summary`) or, when the call succeeded,
passes it on to ``sys.stderr`` (:func:`pass_on`), so nothing printed by another thread in
the meantime is lost.

Descriptors and ``sys.stdout`` are process-wide: a lock makes the capture one at a time (OpenEXR calls of
several threads run one after the other while captured); output that another thread writes
to descriptor 1 or 2 during a capture is delayed to its end (re-emitted on ``sys.stderr``) or,
when the call failed, dropped with the diagnostics. Where the descriptors cannot be
duplicated (closed, or an unusual platform) the call runs uncaptured. Checked by
``tests/test_exr.py::test_damaged_file_prints_nothing_and_costs_one_line``.
"""

import contextlib
import ctypes
import io
import os
import sys
import tempfile
import threading


_LOCK = threading.Lock()


def _flush_c_streams() -> None:
    """Flush C's stdio buffers (C++ ``std::cout`` writes through them): a redirected stdout is
    block-buffered, and what stays in the buffer would reach the real descriptor later."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):  # no C library to load by name (Windows): nothing buffered to flush
        pass


class Captured:
    """What OpenEXR printed during a :func:`captured` block (``text`` is set at its end)."""

    text: str = ""


@contextlib.contextmanager
def captured():
    """Run the block with descriptors 1 and 2 pointing at a temporary file; yields a
    :class:`Captured` whose ``text`` holds what was written there once the block ends
    (normally or by an exception)."""
    out = Captured()
    with _LOCK:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        try:
            saved = [os.dup(1), os.dup(2)]
        except OSError:  # a descriptor is closed: nothing would be seen anyway
            yield out
            return
        python = io.StringIO()
        try:
            with tempfile.TemporaryFile() as sink:
                _flush_c_streams()
                os.dup2(sink.fileno(), 1)
                os.dup2(sink.fileno(), 2)
                try:
                    with contextlib.redirect_stdout(python), contextlib.redirect_stderr(python):
                        yield out
                finally:
                    _flush_c_streams()
                    for fd, copy in zip((1, 2), saved):
                        os.dup2(copy, fd)
                    sink.seek(0)
                    out.text = sink.read().decode("utf-8", "replace") + python.getvalue()
        finally:
            for copy in saved:
                os.close(copy)


def summary(text: str, path: str) -> str:
    """OpenEXR's first diagnostic line as a clause for an error message (``""`` when it said
    nothing), the file name it starts with removed: ``" (OpenEXR: (EXR_ERR_…) …)"``."""
    for line in text.splitlines():
        line = line.strip()
        if line.startswith(path + ": "):
            line = line[len(path) + 2 :]
        if line:
            return f" (OpenEXR: {line.rstrip('.')})"
    return ""


def pass_on(text: str) -> None:
    """Write what a successful call printed to ``sys.stderr`` (nothing is swallowed)."""
    if text:
        sys.stderr.write(text if text.endswith("\n") else text + "\n")
