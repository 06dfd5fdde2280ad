"""The command line's parser and option types: every value checked against its documented
domain while the command line is parsed, before any work starts.

* :class:`Parser` — ``argparse`` without abbreviations (``--walker`` is not ``--walkers``), and
  every option that does not accumulate by design refused when given twice;
* :func:`integer`, :func:`real`, :func:`seed` — option types with their domain in the message
  (argparse prefixes it with the flag: ``argument --steps: must be an integer in [0, 1000000]``);
* :func:`output_file`, :func:`output_directory` — paths checked for writability before the
  work whose result they receive.
"""

import argparse
import math
import os

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
        parser.error(f"argument {'/'.join(action.option_strings)}: given more than once ({option_string}); give it once.")
    seen.add(action.dest)


class Parser(argparse.ArgumentParser):
    """The parser of ``brdfscale`` and of each subcommand (argparse's ``add_parser`` builds
    subparsers of the same class): no abbreviated options, no silently repeated ones."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self.register("action", None, _Once)
        self.register("action", "store", _Once)
        self.register("action", "store_true", _OnceTrue)


def _number(text: str, kind):
    try:
        return kind(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}; got {text!r}") from None


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
                f"must be a finite number in {'(' if strict_lo else '['}{lo:g}, {hi:g}]; got {text!r:.40}")
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
