"""The ``brdfscale`` command.

Each subcommand lives in its own module of this package and exposes ``register(subparsers)``
which adds its parser and sets ``func`` (a callable taking the parsed namespace and returning
an exit status; a subcommand that runs no JAX sets ``compiles=False``, which skips the
persistent compilation cache and keeps its start-up free of JAX). Add new subcommands to
``_SUBCOMMANDS``. Options are parsed by
:class:`._options.Parser` (no abbreviations, no silent repeats) with typed domains.

Exit status (also in ``brdfscale --help``): 0 success; 1 an unexpected failure (a bug: the
message says so and ``--debug`` shows the traceback); 2 a bad command line or input (an option
outside its domain, a damaged file, no BRDF at a scale, an output that exists); 3 the output
directory or checkpoint is in use by another run; 4 ``fit-library`` finished with some materials failed
(each named with its error in the library's index); 5 the fit ran but the model is inadequate for the
data (χ²/dof or residual structure; the line names the scale and the figure); 6 a sampler's chains have not
converged (the line names the failed criterion); 7 the data cannot determine what was asked (e.g. a lobe narrower
than a few pixels per axis, so the statistics' change with scale is unmeasurable); 8 an output could not be
written (disk full or an I/O error: the line names the file and the free space); 130 interrupted (Ctrl-C).
Statuses 5 and 6 come after a complete report is written: the report holds the details; 7 is a
refusal before the work (``fit``: no report; the line holds the details — fitting.resolution).
"""

import contextlib
import errno
import importlib
import re
import sys
import warnings

from .._errors import BrdfscaleError, OutputInUseError, OutputWriteError
from ._options import Parser


_SUBCOMMANDS = ("example", "synth", "topography", "info", "fit", "fit-library", "demo")

EXIT_OK, EXIT_FAILURE, EXIT_USAGE, EXIT_IN_USE, EXIT_INTERRUPTED = 0, 1, 2, 3, 130
EXIT_SOME_FAILED, EXIT_INADEQUATE, EXIT_NOT_CONVERGED, EXIT_UNDETERMINED, EXIT_NOT_WRITTEN = 4, 5, 6, 7, 8

_EPILOG = (
    "exit status: 0 success; 1 unexpected failure (rerun with --debug for the traceback); 2 bad command "
    "line or input (option outside its domain, damaged file, output exists, no BRDF at a scale); 3 output "
    "directory or checkpoint in use by another run; 4 fit-library finished with some materials failed (see its "
    "index); 5 model inadequate for the data; 6 sampler not converged; 7 data cannot determine what was asked; "
    "8 an output could not be written (disk full, I/O error); 130 interrupted."
)


#: The library's messages name Python arguments (``pass overwrite=True``, ``default_sigma=``, a
#: message prefixed ``fixed:``); the command's errors name its flags instead — this mapping,
#: applied by :func:`in_flags`, is the one place where an argument's name becomes a flag
#: (tests/test_choices.py checks that every flag exists). A key ending in ``:`` is a prefix.
FLAGS = {
    "overwrite=True": "--force",
    "force=True": "--force",
    "default_sigma=": "--default-sigma",
    "masking=": "--masking",
    "out_dir=": "--out",
    "out=": "--out",
    "channel=": "--channel",
    "address=": "--address",
    "workers=": "--workers",
    "fixed:": "--fix:",
    "fitting.rewind_checkpoint(path)": "--rewind-checkpoint",
}
_PYTHON_ARGUMENT = re.compile(
    "|".join(
        f"^{re.escape(key)}" if key.endswith(":") else rf"(?<![\w.-]){re.escape(key)}"
        for key in sorted(FLAGS, key=len, reverse=True)
    )
)


def in_flags(message: str) -> str:
    """A library message in the command's words: each Python argument of :data:`FLAGS` as its flag."""
    return _PYTHON_ARGUMENT.sub(lambda match: FLAGS[match.group(0)], message)


def build_parser() -> Parser:
    from .. import __version__

    parser = Parser(
        prog="brdfscale",
        description="Scale-dependent evolution of BRDFs: forward model, synthesis, fitting.",
        epilog=_EPILOG,
    )
    parser.add_argument("--version", action="version", version=f"brdfscale {__version__}")
    parser.add_argument(
        "--no-compilation-cache",
        action="store_true",
        help="compile every XLA program afresh instead of keeping compiled programs between "
        "runs (kept by default in $BRDFSCALE_COMPILATION_CACHE, else "
        "$XDG_CACHE_HOME/brdfscale/jax, by default ~/.cache/brdfscale/jax)",
    )
    parser.add_argument(
        "--debug",
        action="store_true",
        help="show the Python traceback of an unexpected failure instead of a one-line message",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _SUBCOMMANDS:
        importlib.import_module(f"{__name__}._{name.replace('-', '_')}").register(sub)
    parser.subcommands = sub.choices
    return parser


@contextlib.contextmanager
def _one_line_warnings(name: str, debug: bool):
    """A warning raised while a command runs prints as one line on stderr, ``brdfscale CMD: warning: MESSAGE``
    (whitespace collapsed), like the command's errors — not Python's ``file:line: Category: message`` and source
    line, which are kept under ``--debug``. The process's warning filters and ``warnings.showwarning`` are as
    before afterwards (``warnings.catch_warnings``); which warnings show, and how often, is Python's filters' choice."""
    if debug:
        yield
        return

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"{name}: warning: {' '.join(str(message).split())}", file=sys.stderr if file is None else file)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # the subcommand's own usage, not the top level's
        (parser.subcommands.get(args.command) or parser).error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_OK
    name = f"brdfscale {args.command}"
    try:
        if not args.no_compilation_cache and getattr(args, "compiles", True):
            from .._compilation_cache import enable

            enable()
        with _one_line_warnings(name, args.debug):
            return int(args.func(args) or 0)
    except OutputInUseError as err:
        print(f"{name}: error: {in_flags(str(err))}", file=sys.stderr)
        return EXIT_IN_USE
    except OutputWriteError as err:
        print(f"{name}: error: {in_flags(str(err))}", file=sys.stderr)
        return EXIT_NOT_WRITTEN
    except BrdfscaleError as err:
        print(f"{name}: error: {in_flags(str(err))}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{name}: interrupted.", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as err:  # the last resort: a one-line message, never a traceback
        if args.debug:
            raise
        if isinstance(err, OSError) and err.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
            # a full disk met outside brdfscale's writers (a library's scratch file): still no bug
            from .._files import write_failed

            print(
                f"{name}: error: {write_failed(err.filename or '(a file)', err, kept='it may be incomplete')}",
                file=sys.stderr,
            )
            return EXIT_NOT_WRITTEN
        text = " ".join(str(err).split())[:300]
        print(
            f"{name}: unexpected failure ({type(err).__name__}: {text}); rerun as `brdfscale --debug "
            f"{args.command} ...` for the traceback, and report it if it is not the machine's (memory, disk).",
            file=sys.stderr,
        )
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
