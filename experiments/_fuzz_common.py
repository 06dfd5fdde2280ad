"""What the fuzz families of experiments/fuzz_robustness.py (``experiments/_fuzz_<family>.py``,
issue 34) share: their tallies (:func:`tally`), ``brdfscale`` run in this process
(:func:`in_process`) and their command line (:func:`main`):

    python -m experiments._fuzz_<family> [--quick] [--seed N] [--json PATH]

prints the family's result as JSON (and writes it to PATH) and exits 0 exactly when no trial
was bad. Each family exposes ``run(quick, seed=0, directory=None) -> {"kinds": {kind:
tally}, "bad_examples": [...], …}``; fuzz_robustness.py runs them in turn.
"""

import argparse
import json
import warnings


#: What a family counts per kind of trial: tried = refused + same + bad (the families' docstrings
#: say what each verdict means for them).
OUTCOMES = ("tried", "refused", "same", "bad")


def tally(kinds) -> dict[str, dict[str, int]]:
    """An empty tally for each of ``kinds``."""
    return {kind: dict.fromkeys(OUTCOMES, 0) for kind in kinds}


def in_process(argv: list[str], *, quiet: bool = False) -> tuple[int, str, str]:
    """``brdfscale ARGV`` in this process, without the persistent compilation cache: (exit status,
    stdout, stderr) — tests.helpers.run_cli; an exception that escaped ``main`` is status −1
    (bad for every family). ``quiet``: Python warnings are not shown (a reader's own warnings
    about a damaged file are not the command's output)."""
    from tests.helpers import run_cli

    with warnings.catch_warnings():
        if quiet:
            warnings.simplefilter("ignore")
        return run_cli(argv)


def main(run, doc: str, argv=None) -> int:
    """The family's command line (module docstring) around its ``run``; ``doc`` its docstring."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the smoke-test size (the family's docstring)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", default=None, help="write the result here as JSON too")
    args = parser.parse_args(argv)
    result = run(args.quick, seed=args.seed)
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        from brdfscale import files

        files.write_text(args.json, text + "\n", overwrite=True)
    return 0 if all(r["bad"] == 0 for r in result["kinds"].values()) else 1
