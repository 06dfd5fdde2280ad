"""A hint when the ``brdfscale`` being imported is not the installed one.

A folder named ``brdfscale`` in the current directory or next to a script (a clone of the
repository, an old copy of the package) comes first on ``sys.path`` and can shadow the
installed package. Two cases, measured with Python 3.11 and setuptools' editable install:

* the folder has no ``__init__.py`` (a clone's top level): Python makes it a *namespace
  package*. A regular installed package still wins over it, but an editable install
  (``pip install -e``, whose modules are found by a finder after the path search) loses:
  ``import brdfscale`` succeeds and ``brdfscale.evolve`` raises ``AttributeError: module
  'brdfscale' has no attribute 'evolve'``. None of brdfscale's code runs then — not this
  module, not ``brdfscale/__init__.py`` — so no hint can come from the package; the fix is
  documented in the README's quick start (rename the folder, run from another directory, or
  ``python -P`` / ``PYTHONSAFEPATH=1``, which leave the script's directory off the path);
* the folder has an ``__init__.py`` (a copy or another checkout of the package): its own
  ``__init__`` runs, and when a name it lacks is asked for, :func:`hint` compares its location
  with the installed distribution's (``importlib.metadata``: the files of a regular install,
  ``direct_url.json`` of an editable one) and names both.

Checked by ``tests/test_layout.py::test_a_shadowing_copy_of_the_package_names_the_installed_one``.
"""

import json
import os


def _installed_location() -> tuple[str, str] | None:
    """(version, directory of the installed ``brdfscale`` package), or None when brdfscale is
    not installed or its location cannot be told."""
    from importlib.metadata import distribution, PackageNotFoundError

    try:
        dist = distribution("brdfscale")
    except PackageNotFoundError:
        return None
    direct = dist.read_text("direct_url.json")
    if direct:
        try:
            info = json.loads(direct)
        except ValueError:
            info = {}
        url = info.get("url", "")
        if info.get("dir_info", {}).get("editable") and url.startswith("file://"):
            from urllib.parse import unquote, urlparse

            return dist.version, os.path.join(unquote(urlparse(url).path), "brdfscale")
    for file in dist.files or ():
        if file.parts == ("brdfscale", "__init__.py"):
            return dist.version, os.path.dirname(str(dist.locate_file(file)))
    return None


def hint(here: str) -> str:
    """A sentence for an AttributeError of the package whose ``__init__.py`` is ``here``:
    ``""`` when it is the installed package (or nothing is installed), else where each is
    and how to reach the installed one."""
    try:
        installed = _installed_location()
    except Exception:  # noqa: BLE001 — a hint must never replace the error it explains
        return ""
    if installed is None:
        return ""
    version, location = installed
    this = os.path.dirname(os.path.realpath(here))
    if os.path.realpath(location) == this:
        return ""
    return (
        f" (this brdfscale is {this}, not the installed brdfscale {version} at {location}: a folder named "
        "brdfscale in the current directory or next to the script shadows it; rename the folder, run from "
        "another directory, or start Python with -P)"
    )
