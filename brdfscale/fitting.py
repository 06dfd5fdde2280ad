"""``brdfscale.fitting``: the :mod:`fitting` package, under a name no local file can shadow.

brdfscale's inverse-fitting package is installed as the top-level package ``fitting``. A file
or folder named ``fitting`` in the working directory (or anywhere earlier on ``sys.path``)
would take its place on ``import fitting`` and fail later with an AttributeError. Importing
it as ``from brdfscale import fitting`` (or ``import brdfscale.fitting``) finds the package
installed beside brdfscale and refuses, with an ImportError naming the file, anything else
that has taken the name. This module replaces itself in ``sys.modules`` by that package, so
``brdfscale.fitting`` and ``fitting`` are the same module object (no duplicated classes).

Tested in tests/test_imports.py.
"""

import importlib
import importlib.util
import sys
from pathlib import Path


def _load():
    expected = Path(__file__).resolve().parent.parent / "fitting" / "__init__.py"
    loaded = sys.modules.get("fitting")
    if loaded is None:
        spec = importlib.util.find_spec("fitting")
        origin = getattr(spec, "origin", None)
        if spec is not None and origin and Path(origin).resolve() != expected and expected.exists():
            raise ImportError(
                f"the name 'fitting' is taken by {origin}, which shadows brdfscale's fitting package "
                f"({expected.parent}); rename that file or folder, or move it off the Python path."
            )
        loaded = importlib.import_module("fitting")
    if getattr(loaded, "__distribution__", None) != "brdfscale":
        where = getattr(loaded, "__file__", None) or repr(loaded)
        raise ImportError(
            f"the module imported as 'fitting' ({where}) is not brdfscale's fitting package; rename that file "
            "or folder, or move it off the Python path, and restart the interpreter."
        )
    return loaded


sys.modules[__name__] = _load()
