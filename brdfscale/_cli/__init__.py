"""The ``brdfscale`` command.

Each subcommand lives in its own module of this package and exposes ``register(subparsers)``
which adds its parser and sets ``func`` (a callable taking the parsed namespace and returning
an exit status). Add new subcommands to ``_SUBCOMMANDS``.
"""

import argparse
import importlib
import sys

from .._errors import BrdfscaleError

_SUBCOMMANDS = ("example", "synth", "info", "fit", "demo")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="brdfscale",
        description="Scale-dependent evolution of BRDFs: forward model, synthesis, fitting.",
    )
    parser.add_argument("--version", action="version", version=f"brdfscale {__version__}")
    parser.add_argument("--no-compilation-cache", action="store_true",
                        help="compile every XLA program afresh instead of keeping compiled programs between "
                        "runs (kept by default in $BRDFSCALE_COMPILATION_CACHE, else ~/.cache/brdfscale/jax)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _SUBCOMMANDS:
        importlib.import_module(f"{__name__}._{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    if not args.no_compilation_cache:
        from ._compilation_cache import enable

        enable()
    try:
        return int(args.func(args) or 0)
    except BrdfscaleError as err:
        print(f"brdfscale {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
