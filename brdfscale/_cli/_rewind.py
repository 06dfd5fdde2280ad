"""``brdfscale fit … --rewind-checkpoint``: keep the verified chunks of a damaged ``DIR/chain.h5``
(:func:`fitting.rewind_checkpoint`) before the run samples, so that it continues from the last
good chunk — the remedy a refused damaged checkpoint names (``brdfscale._cli.FLAGS`` turns the
library's ``fitting.rewind_checkpoint(path)`` into this flag). Tested in tests/test_cli_rewind.py."""

import os

from .._errors import InvalidInputError


def add_rewind_option(parser) -> None:
    parser.add_argument(
        "--rewind-checkpoint",
        action="store_true",
        help="before sampling, keep the chunks of a damaged DIR/chain.h5 that verify (fitting.rewind_checkpoint) "
        "and continue from the last good one; a checkpoint that verifies whole is left as it is",
    )


def rewind(fitting, checkpoint: str, force: bool) -> str:
    """Rewind ``checkpoint`` and say so in one line.

    Raises:
        InvalidInputError: with ``--force`` (which starts the chain afresh: nothing to keep), or
            when there is no checkpoint to rewind.
        MeasurementFileError: no part of it can be kept (from :func:`fitting.rewind_checkpoint`).
    """
    if force:
        raise InvalidInputError(
            "--rewind-checkpoint keeps the verified steps of DIR/chain.h5 and --force starts it afresh: give one."
        )
    if not os.path.isfile(checkpoint):
        raise InvalidInputError(f"--rewind-checkpoint: there is no checkpoint {checkpoint} to rewind.")
    steps = fitting.rewind_checkpoint(checkpoint)
    return f"rewound {checkpoint}: its first {steps} steps verify and are kept; sampling continues from step {steps}"
