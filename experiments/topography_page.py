"""The figures of docs/topography.md ("Your own surface"), drawn by the page's own code.

Runs every ``python`` block of the page in order, in one namespace, from the repository root
(as a reader of the page would, and as tests/test_docs.py does), prints what each block
prints, and saves every figure the code leaves in a variable named ``fig_<name>`` as
``experiments/results/topography_page/<name>.png`` — the files the page shows. So the page's
figures are the page's code, not a copy of it.

Run:  python -m experiments.topography_page [--check | --update-text]

``--check`` also compares each block's output with the ``text`` block that follows it on the
page (what tests/test_docs.py checks: the same words and numbers, runs of white space counted
as one) and exits with status 1 on a difference; ``--update-text`` rewrites those text blocks
with what the blocks print (after a change of the code or of the library). Needs the
``topography`` extra (SurfaceTopography).
"""

import argparse
import contextlib
import io
import os
import re
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "topography.md"
FIGURES = ROOT / "experiments" / "results" / "topography_page"


def blocks(path: Path = PAGE) -> list[tuple[int, str, str | None]]:
    """``(line, python code, text shown under it or None)`` for every python block of the page;
    the shown text is a ``text`` block that follows the python block with only blank lines
    between them."""
    lines = path.read_text(encoding="utf-8").splitlines()
    fenced = []  # (language, first line number, body)
    k = 0
    while k < len(lines):
        m = re.match(r"^```(\w*)\s*$", lines[k])
        if m and m.group(1):
            start, body = k + 1, []
            k += 1
            while k < len(lines) and not lines[k].startswith("```"):
                body.append(lines[k])
                k += 1
            if k == len(lines):
                raise ValueError(f"{path}:{start}: a {m.group(1)} block is not closed")
            fenced.append((m.group(1), start + 1, start, k, "\n".join(body) + "\n"))
        k += 1
    out = []
    for n, (language, first, start, end, body) in enumerate(fenced):
        if language != "python":
            continue
        shown = None
        if n + 1 < len(fenced) and fenced[n + 1][0] == "text":
            between = lines[end + 1 : fenced[n + 1][2] - 1]
            if all(not line.strip() for line in between):
                shown = fenced[n + 1][4]
        out.append((first, body, shown))
    return out


def run(path: Path = PAGE) -> tuple[dict, list[tuple[int, str, str | None]]]:
    """Execute the page's python blocks in order from the repository root; returns the
    namespace and ``(line, printed output, shown text)`` per block."""
    namespace = {"__name__": "__topography_page__"}
    outputs = []
    here = os.getcwd()
    os.chdir(ROOT)
    try:
        for line, code, shown in blocks(path):
            buffer = io.StringIO()
            with contextlib.redirect_stdout(buffer):
                exec(compile(code, f"{path}:{line}", "exec"), namespace)  # noqa: S102 — the page's own code
            outputs.append((line, buffer.getvalue(), shown))
    finally:
        os.chdir(here)
    return namespace, outputs


def same(printed: str, shown: str) -> bool:
    """The printed output and the shown text hold the same words and numbers (the page may
    wrap a long printed line)."""
    return printed.split() == shown.split()


def differences(outputs) -> list[str]:
    """The blocks whose printed output is not the text the page shows under them."""
    bad = []
    for line, printed, shown in outputs:
        if shown is not None and not same(printed, shown):
            bad.append(f"docs/topography.md:{line}: the block prints\n{printed}\nbut the page shows\n{shown}")
    return bad


def update_text(outputs, path: Path = PAGE) -> int:
    """Replace each shown text block with what its python block printed; returns how many changed."""
    lines = path.read_text(encoding="utf-8").splitlines()
    changed = 0
    for line, printed, shown in sorted(outputs, reverse=True):  # from the end: line numbers stay valid
        if shown is None or same(printed, shown):
            continue
        k = line - 1
        while not lines[k].startswith("```"):  # the end of the python block
            k += 1
        k += 1
        while not lines[k].startswith("```text"):
            k += 1
        end = k + 1
        while not lines[end].startswith("```"):
            end += 1
        lines[k + 1 : end] = printed.rstrip("\n").split("\n")
        changed += 1
    if changed:
        from brdfscale import files

        files.write_text(path, "\n".join(lines) + "\n", overwrite=True)
    return changed


def figures(namespace: dict) -> dict:
    """``name → Figure`` for every ``fig_<name>`` the page's code made."""
    from matplotlib.figure import Figure

    return {key[4:]: value for key, value in namespace.items() if key.startswith("fig_") and isinstance(value, Figure)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--check", action="store_true", help="compare each block's output with the page's text block")
    group.add_argument("--update-text", action="store_true", help="rewrite the page's text blocks with the output")
    args = parser.parse_args(argv)
    namespace, outputs = run()
    for line, printed, _ in outputs:
        if printed:
            print(f"-- docs/topography.md:{line}\n{printed}", end="" if printed.endswith("\n") else "\n")
    from brdfscale import files

    FIGURES.mkdir(parents=True, exist_ok=True)
    for name, fig in figures(namespace).items():
        path = FIGURES / f"{name}.png"
        files.atomic_write(path, lambda tmp, fig=fig: fig.savefig(tmp, dpi=110, format="png"), overwrite=True)
        print(f"wrote {path.relative_to(ROOT)}")
    if args.update_text:
        print(f"updated {update_text(outputs)} text blocks of {PAGE.relative_to(ROOT)}")
    if args.check:
        bad = differences(outputs)
        for problem in bad:
            print(problem, file=sys.stderr)
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
