"""Fuzz family "disk": every command on a disk that fills (issue 34, build item 2).

Each command (synth, topography, fit with the solver only, fit with a sampler, fit-library,
demo) runs, in its own process, with its outputs on a tmpfs filled until 0, 4 KiB, 64 KiB,
1 MiB or ample space is free. A trial is

* ``same``: the command completed as it does with ample space (its exit status) and every file
  it left is complete (JSON parses, EXR reads back, PNG ends with its IEND chunk, NetCDF and
  HDF5 open);
* ``refused``: exit 8 with one error line on stderr naming the file and "not written" (its last
  line; no traceback, no other error),
  nothing corrupt left (every file present complete, no temporary file), and the same command
  rerun with the space freed completes (the ample run's status, every output complete);
* ``bad``: anything else (a traceback, a segfault, exit 1, a corrupt or empty file left, a
  temporary file left, a rerun that does not complete).

Where ``mount -t tmpfs`` cannot be used (not root, not Linux), the test seam
``brdfscale._files._fault`` raises ENOSPC instead, at each step of
``brdfscale._files.STEPS`` of the command's first write (five trials per command like the five
levels); the JSON says which (``"mode"``). ``quick`` runs synth (at two steps) and topography
(at one) only, injected, in this process (fast enough for the default test suite).

    python -m experiments._fuzz_disk [--quick] [--json results.json]
"""

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from experiments import _fuzz_common
from tests.references.damage import fill, mount_tmpfs


ROOT = Path(__file__).resolve().parent.parent
TOPOGRAPHY = ROOT / "tests" / "data" / "topographies" / "di-3.di"
LEVELS = {"0": 0, "4KiB": 4 << 10, "64KiB": 64 << 10, "1MiB": 1 << 20, "ample": None}
STEPS = ("write", "flush", "fsync", "close", "rename")  # brdfscale._files.STEPS (checked in the test)
_TMPFS_SIZE = "192m"
_QUICK = {"synth": ("write", "fsync"), "topography": ("rename",)}  # quick mode's injected steps
_SYNTH = ("--size", "64", "--scales", "4,16", "--pixels", "9")

#: The child process: ``brdfscale ARGV`` with, when BRDFSCALE_FUZZ_FAULT=STEP, ENOSPC raised by
#: the test seam at STEP of the first write. Its exit status is the command's (a signal: −N).
#: The child process: ``brdfscale ARGV`` (through :func:`_child`) with, when
#: BRDFSCALE_FUZZ_FAULT=STEP, ENOSPC raised by the test seam at STEP of the first write. Its exit
#: status is the command's (a signal: −N).
_CHILD = ("-m", "experiments._fuzz_disk", "--child")


def _child(argv: list[str]) -> int:
    with _faulty(os.environ.get("BRDFSCALE_FUZZ_FAULT")):
        from brdfscale._cli import main

        return main(argv)


@contextlib.contextmanager
def _faulty(step: str | None):
    """With ``step``: the test seam raises ENOSPC at ``step`` of the first write of an output
    (the lock's holder record, which only informs and whose failure is ignored, is skipped)."""
    if not step:
        yield
        return
    import errno

    from brdfscale import _files

    fired = []

    def fault(at: str, tmp: str) -> None:
        if at == step and not fired and ".holder.json" not in tmp:
            fired.append(tmp)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    previous = _files._fault
    _files._fault = fault
    try:
        yield
    finally:
        _files._fault = previous


def _commands(inputs: Path, out: Path, quick: bool) -> dict[str, list[str]]:
    """The command lines, each writing under ``out`` (a directory that exists)."""
    commands = {
        "synth": [
            "synth",
            "gaussian",
            "--out",
            str(out / "x.exr"),
            "--size",
            "64",
            "--scales",
            "4,16",
            "--pixels",
            "9",
        ],
        "topography": ["topography", str(TOPOGRAPHY), "--scales", "1px,4px", "--bins", "17", "--out", str(out / "t")],
    }
    if quick:
        return commands
    data = str(inputs / "data.exr")
    fit = ["fit", data, "--model", "parametric", "--starts", "2", "--no-progress", "--seed", "1"]
    commands.update(
        {
            "fit": [*fit, "--steps", "0", "--out", str(out / "f")],
            "fit-sampler": [
                *fit,
                *("--sampler", "emcee", "--chains", "2", "--walkers", "16", "--steps", "60"),
                *("--out", str(out / "s")),
            ],
            "fit-library": [
                *("fit-library", str(inputs / "library"), "--out", str(out / "l")),
                *("--starts", "2", "--no-progress", "--steps", "0"),
            ],
            "demo": ["demo", "--out", str(out / "d"), "--steps", "0", "--no-progress"],
        }
    )
    return commands


def _prepare(inputs: Path) -> None:
    """The inputs (outside the tmpfs): lobes a parametric Beckmann model fits adequately
    (tests/test_fit_cli.py's) as ``data.exr`` and a library of two such materials."""
    import jax

    jax.config.update("jax_enable_x64", True)  # fitting.simulate's precision (as the commands set it)
    from brdfscale import exr, fitting

    truth = dict(amplitude=1.0, alpha_lobe=0.1, alpha_max=0.3, mu_c=4.0, exponent=1.0)
    (inputs / "library").mkdir()
    for seed, path in ((3, inputs / "data.exr"), (4, inputs / "library" / "a.exr"), (5, inputs / "library" / "b.exr")):
        mset = fitting.simulate(
            fitting.ParametricModel(), truth, (1.0, 4.0, 16.0), size=25, extent=0.5, noise=0.02, floor=1e-3, seed=seed
        )
        exr.write_measurements(path, mset)


def _run(argv: list[str], env: dict, fault: str | None = None, timeout: float = 900) -> tuple[int, str]:
    """``brdfscale ARGV``: (exit status, stderr) — in a child process, where a segfault shows
    as −11, or (quick mode, ``env["BRDFSCALE_FUZZ_INPROCESS"]``) in this one."""
    if env.get("BRDFSCALE_FUZZ_INPROCESS"):
        return _run_here(argv, fault)
    child_env = dict(env)
    if fault:
        child_env["BRDFSCALE_FUZZ_FAULT"] = fault
    try:
        r = subprocess.run(
            [sys.executable, *_CHILD, *argv],
            env=child_env,
            capture_output=True,
            text=True,
            timeout=timeout,
            cwd=env["BRDFSCALE_FUZZ_CWD"],
        )
    except subprocess.TimeoutExpired:
        return -999, "timed out"
    return r.returncode, r.stderr


def _run_here(argv: list[str], fault: str | None) -> tuple[int, str]:
    import io
    import traceback

    from brdfscale._cli import main

    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err), _faulty(fault):
        try:
            code = main(["--no-compilation-cache", *argv])
        except SystemExit as exit_:
            code = exit_.code if isinstance(exit_.code, int) else 1
        except BaseException:  # noqa: BLE001 — main() must never let one out: a finding
            traceback.print_exc(file=err)
            code = -1
    return code, err.getvalue()


# -- what is left -----------------------------------------------------------------------------------


def _complete(path: Path) -> str | None:
    """None when ``path`` is a complete file of its kind, else what is wrong with it."""
    name = path.name
    if ".brdfscale-" in name and ".tmp" in name:
        return "a temporary file left behind"
    if name.endswith(".lock") or name.endswith(".holder.json") or name == ".brdfscale-demo":
        return None  # the lock (empty by design), its record (informative), the demo's marker
    if path.stat().st_size == 0:
        return "an empty file"
    suffix = path.suffix
    try:
        if suffix == ".json":
            json.loads(path.read_text(encoding="utf-8"))
        elif suffix == ".exr":
            from brdfscale import exr

            with contextlib.suppress(Exception):
                exr.read_measurements(path)
                return None
            exr.read_lobe_table(path)
        elif suffix == ".png":
            data = path.read_bytes()
            if not (data.startswith(b"\x89PNG\r\n\x1a\n") and data.endswith(b"IEND\xaeB`\x82")):
                return "a truncated PNG"
        elif suffix in (".nc", ".h5"):
            import h5py

            with h5py.File(path, "r") as f:
                list(f.keys())
        elif suffix == ".md":
            path.read_text(encoding="utf-8")
    except Exception as err:  # noqa: BLE001 — any failure to read is the finding
        return f"unreadable ({type(err).__name__}: {' '.join(str(err).split())[:120]})"
    return None


def _damage(out: Path) -> list[str]:
    found = []
    for path in sorted(out.rglob("*")):
        if path.is_file() and path.name != "filler":
            problem = _complete(path)
            if problem:
                found.append(f"{path.relative_to(out)}: {problem}")
    return found


def _outputs(out: Path) -> set[str]:
    return {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and p.name != "filler"}


# -- the disk ---------------------------------------------------------------------------------------


def _fill(disk: Path, leave: int | None) -> Path:
    """``disk`` filled until ``leave`` bytes are free (None: left as it is); the filler's path."""
    return disk / "filler" if leave is None else Path(fill(disk, leave))


def _clear(disk: Path) -> None:
    for p in disk.iterdir():
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()


# -- the study --------------------------------------------------------------------------------------


def _one_line(err: str) -> str | None:
    """The error line when stderr ends with exactly one ``brdfscale CMD: error: … not written …``
    line and holds no other error and no traceback (a command's progress lines may precede it)."""
    lines = [line for line in err.strip().splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("brdfscale ") and ": error: " in line]
    if (
        lines
        and errors == [lines[-1]]
        and " not written" in lines[-1]
        and not any("Traceback" in line or "Exception ignored" in line for line in lines)
    ):
        return lines[-1]
    return None


def _trial(kind, argv, disk, out, env, baseline, *, leave=None, fault=None) -> tuple[str, str]:
    """("same" | "refused" | "bad", why)."""
    _clear(disk)
    out.mkdir()
    filler = _fill(disk, leave)
    code, err = _run(argv, env, fault)
    left = _damage(out)
    outputs = _outputs(out)
    if code == baseline["code"] and not left and outputs >= baseline["outputs"]:
        return "same", ""
    tail = " ".join(err.strip().splitlines()[-2:])[-200:]
    if code != 8:
        return "bad", f"exit {code} (expected {baseline['code']} or 8): {tail}"
    if _one_line(err) is None:
        return "bad", f"exit 8 but not one 'not written' line: {' | '.join(err.strip().splitlines())[:200]}"
    if left:
        return "bad", f"exit 8 left {'; '.join(left)[:200]}"
    with contextlib.suppress(FileNotFoundError):
        filler.unlink()
    code, err = _run(argv, env)
    left, outputs = _damage(out), _outputs(out)
    if code != baseline["code"] or left or not outputs >= baseline["outputs"]:
        missing = sorted(baseline["outputs"] - outputs)
        why = f"exit {code}" + (f", left {left[:2]}" if left else "") + (f", missing {missing[:3]}" if missing else "")
        return "bad", f"rerun with space did not complete ({why}): {' '.join(err.strip().splitlines()[-1:])[:160]}"
    return "refused", ""


def run(quick: bool, seed: int = 0, directory: str | None = None) -> dict:
    """The family's counts (see the module's docstring). ``seed`` is unused: the trials are a
    fixed grid (every command × every level or step), deterministic by construction."""
    del seed
    work = Path(tempfile.mkdtemp(prefix="brdfscale-fuzz-disk-", dir=directory))
    disk, inputs, cwd = work / "disk", work / "inputs", work / "cwd"
    for d in (disk, inputs, cwd):
        d.mkdir()
    env = {
        **os.environ,
        "BRDFSCALE_COMPILATION_CACHE": str(work / "cache"),  # off the small disk, shared by the runs
        "BRDFSCALE_PROGRESS": "0",
        "MPLBACKEND": "Agg",
        "BRDFSCALE_FUZZ_CWD": str(cwd),
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
        **({"BRDFSCALE_FUZZ_INPROCESS": "1"} if quick else {}),
    }
    why_not = "quick mode injects" if quick else mount_tmpfs(disk, _TMPFS_SIZE)
    mounted = why_not is None
    mode = "tmpfs" if mounted else "injected"
    result: dict = {
        "mode": mode,
        "mode_note": (
            f"outputs on a {_TMPFS_SIZE} tmpfs filled to leave " + ", ".join(LEVELS) + " free"
            if mounted
            else f"ENOSPC injected through brdfscale._files._fault at each of {', '.join(STEPS)} ({why_not})"
        ),
        "kinds": {},
        "bad_examples": [],
        "trials": [],
    }
    try:
        out = disk / "out"
        commands = _commands(inputs, out, quick)
        if not quick:
            _prepare(inputs)
        for kind, argv in commands.items():
            counts = _fuzz_common.tally([kind])[kind]
            result["kinds"][kind] = counts
            _clear(disk)
            out.mkdir()
            code, err = _run(argv, env)  # ample space (the tmpfs empty): what completing looks like
            baseline = {"code": code, "outputs": _outputs(out)}
            if code not in (0, 5, 6, 7) or _damage(out) or not baseline["outputs"]:
                counts["tried"] += 1
                counts["bad"] += 1
                result["bad_examples"].append(f"{kind}: fails with ample space: exit {code}: {err.strip()[-200:]}")
                continue
            if mounted:  # the ample level is the baseline run itself: it completed, leaving complete files
                counts["tried"] += 1
                counts["same"] += 1
            trials = (
                [{"leave": v} for v in LEVELS.values() if v is not None]
                if mounted
                else [{"fault": s} for s in (_QUICK[kind] if quick else STEPS)]
            )
            for t in trials:
                outcome, why = _trial(kind, argv, disk, out, env, baseline, **t)
                counts["tried"] += 1
                counts[outcome] += 1
                level = t.get("fault") or next(k for k, v in LEVELS.items() if v == t["leave"])
                result["trials"].append({"kind": kind, "level": level, "outcome": outcome})
                if outcome == "bad" and len(result["bad_examples"]) < 20:
                    result["bad_examples"].append(f"{kind} at {level}: {why}")
    finally:
        if mounted:
            subprocess.run(["umount", str(disk)], check=False)
        shutil.rmtree(work, ignore_errors=True)
    return result


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        return _child(argv[1:])
    return _fuzz_common.main(run, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
