"""Fuzz family ``library`` (issue 34): damaged library indices and SIGKILLed ``brdfscale fit-library`` runs.

A small library (2 materials quick, 3 full: truths of ``tests.helpers``' synthetic library, all
16 px at five scales) is fitted once,
uninterrupted, in this process: the reference (``--starts 1 --batch 1``, solver only, no
figures). Then:

* ``damaged_index`` — a copy of the reference output is damaged, and the same command is run
  again in this process (``brdfscale._cli.main``). Damage: raw bytes of ``library.json``
  (bit flip, byte set, truncation, insertion, deletion), whole replacements (``[]``, ``null``,
  empty, a 5 000-digit integer, 100 000 levels of nesting, not UTF-8, NaN), a key removed or
  a value of another type anywhere in the index, ``materials/`` or a material's directory
  swapped for a file or a symbolic link, ``library.json`` made a directory, a material's report
  deleted or damaged (``fit.json`` deleted, truncated, not an object; a listed file deleted;
  the directory deleted), the index deleted, a stale ``.NAME.partial`` directory beside it.
  ``refused``: exit 2 with one line ``brdfscale fit-library: error: …`` and ``library.json``
  left byte for byte as it was; ``same``: exit 0 and the library complete — every material
  done in the index, its report's θ and χ² those of the reference (relative 1e-9), no
  ``.partial`` directory or temporary file left. Anything else is ``bad``.
* ``sigkill_fit_library`` — the command as a subprocess (every other trial with
  ``--workers 2``, a local Ray instance; the others in-process), SIGKILLed (the driver's PID
  alone) at a time drawn uniformly over 90 % of an uninterrupted run's duration (quick: of 2.2 s); then every process it
  started must be gone within 10 s (``stray``: bad), and the same command run again must exit
  0 with the library complete and equal to the reference as above (``same``), again leaving
  no process behind.

The subprocesses share a compilation cache private to the study's temporary directory. Quick:
6 damaged indices and one in-process kill; full: 64 damaged indices and 22 kills.
"""

import contextlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from brdfscale._watchdog import alive, descendants
from experiments import _fuzz_common


KINDS = ("damaged_index", "sigkill_fit_library")
ARGS = ["--starts", "1", "--batch", "1", "--no-progress"]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INDEX = "library.json"


def _results(out: str, names) -> dict:
    """θ and χ² of each material's report in ``out``."""
    found = {}
    for name in names:
        with open(os.path.join(out, "materials", name, "fit.json")) as f:
            opt = json.load(f)["optimisation"]
        found[name] = (opt["theta"], opt["chi2"])
    return found


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-9 * max(abs(a), abs(b), 1e-300)


def _complete(out: str, reference: dict) -> str | None:
    """Why the library in ``out`` is not complete and equal to ``reference``, or None."""
    try:
        with open(os.path.join(out, INDEX)) as f:
            index = json.load(f)
        states = {n: index["materials"][n]["status"] for n in reference}
        if set(states.values()) != {"done"}:
            return f"statuses {states}"
        got = _results(out, reference)
    except (OSError, ValueError, KeyError, TypeError) as err:
        return f"{type(err).__name__}: {err}"
    for name, (theta, chi2) in reference.items():
        if len(got[name][0]) != len(theta) or not all(map(_close, got[name][0], theta)):
            return f"{name}: θ {got[name][0]} differs from {theta}"
        if not _close(got[name][1], chi2):
            return f"{name}: χ² {got[name][1]} differs from {chi2}"
    left = [n for n in os.listdir(os.path.join(out, "materials")) if n.endswith(".partial")]
    left += [n for n in os.listdir(out) if n.startswith(f".{INDEX}.brdfscale-")]
    return f"left behind: {left}" if left else None


# -- damaged indices ---------------------------------------------------------------------------------


def _paths(node, prefix=()):
    """Every key path in a JSON document (dict keys and list indices)."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        yield (*prefix, key)
        yield from _paths(value, (*prefix, key))


def _at(doc, path):
    for key in path[:-1]:
        doc = doc[key]
    return doc


OTHER_VALUES = (None, True, False, -1, 0, 1.5, 1e308, "x", "../../elsewhere", [], {}, [1, 2], {"a": 1})


def _damage(rng: random.Random, out: str, names: list) -> str:
    """Damage the library in ``out`` one way; return what was done."""
    index = os.path.join(out, INDEX)
    kind = rng.choice(("bytes", "bytes", "whole", "key", "key", "type", "type", "type", "paths", "report"))
    if kind == "bytes":
        data = bytearray(open(index, "rb").read())
        op, at = rng.choice(("flip", "set", "truncate", "insert", "delete")), rng.randrange(len(data))
        if op == "flip":
            data[at] ^= 1 << rng.randrange(8)
        elif op == "set":
            data[at] = rng.randrange(256)
        elif op == "truncate":
            del data[at:]
        elif op == "insert":
            data[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        else:
            del data[at : at + rng.randint(1, 16)]
        with open(index, "wb") as f:
            f.write(data)
        return f"library.json: {op} at byte {at}"
    if kind == "whole":
        text = rng.choice(
            (b"[]", b"null", b"", b'"text"', b"0", b"9" * 5000, b"[" * 100_000 + b"]" * 100_000, b"\xff\xfe{}", b"NaN")
        )
        with open(index, "wb") as f:
            f.write(text)
        return f"library.json replaced by {text[:12]!r}{'…' if len(text) > 12 else ''}"
    doc = json.load(open(index))
    if kind in ("key", "type"):
        paths = [p for p in _paths(doc) if kind == "type" or isinstance(_at(doc, p), dict)]
        path = rng.choice(paths)
        if kind == "key":
            del _at(doc, path)[path[-1]]
            what = f"key {'/'.join(map(str, path))} removed"
        else:
            value = rng.choice([v for v in OTHER_VALUES if type(v) is not type(_at(doc, path)[path[-1]])])
            if rng.random() < 0.1:
                value = [[[]]] * 3 if rng.random() < 0.5 else json.loads("[" * 900 + "]" * 900)
            _at(doc, path)[path[-1]] = value
            what = f"{'/'.join(map(str, path))} set to {json.dumps(value)[:40]}"
        with open(index, "w") as f:
            json.dump(doc, f)
        return what
    name = rng.choice(names)
    material = os.path.join(out, "materials", name)
    if kind == "paths":
        op = rng.choice(("materials file", "material file", "material link", "index directory", "partial junk"))
        if op == "materials file":
            shutil.rmtree(os.path.join(out, "materials"))
            open(os.path.join(out, "materials"), "w").close()
        elif op == "material file":
            shutil.rmtree(material)
            open(material, "w").close()
        elif op == "material link":
            shutil.rmtree(material)
            os.symlink(os.path.join(out, "materials", [n for n in names if n != name][0]), material)
        elif op == "index directory":
            os.remove(index)
            os.mkdir(index)
        else:
            os.makedirs(os.path.join(out, "materials", f".{name}.partial"))
            with open(os.path.join(out, "materials", f".{name}.partial", "fit.json"), "w") as f:
                f.write("{")
        return f"{op} ({name})"
    op = rng.choice(("fit.json deleted", "fit.json truncated", "fit.json a list", "table deleted", "directory deleted"))
    op = rng.choice((op, "index deleted"))
    fit = os.path.join(material, "fit.json")
    if op == "fit.json deleted":
        os.remove(fit)
    elif op == "fit.json truncated":
        text = open(fit).read()
        with open(fit, "w") as f:
            f.write(text[: rng.randrange(len(text))])
    elif op == "fit.json a list":
        with open(fit, "w") as f:
            f.write("[]")
    elif op == "table deleted":
        os.remove(os.path.join(material, "evolved_lobes.exr"))
    elif op == "directory deleted":
        shutil.rmtree(material)
    else:
        os.remove(index)
    return f"{op} ({name})"


def _snapshot(path: str):
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError:
        return None


def _damaged_indices(n, rng, tmp, lib, ref, reference, counts, bad):
    for k in range(n):
        out = os.path.join(tmp, f"damaged-{k}")
        shutil.copytree(ref, out, symlinks=True)
        what = _damage(rng, out, sorted(reference))
        before = _snapshot(os.path.join(out, INDEX))
        code, _, err = _fuzz_common.in_process(["fit-library", lib, "--out", out, *ARGS])
        lines = err.strip().splitlines()
        counts["tried"] += 1
        if code == 2 and len(lines) == 1 and lines[0].startswith("brdfscale fit-library: error: "):
            if _snapshot(os.path.join(out, INDEX)) == before:
                counts["refused"] += 1
            else:
                counts["bad"] += 1
                bad.append(f"damaged_index: {what}: refused, but library.json was changed")
        else:
            problem = _complete(out, reference) if code == 0 else (lines[-1][:160] if lines else "no message")
            if problem is None:
                counts["same"] += 1
            else:
                counts["bad"] += 1
                bad.append(f"damaged_index: {what}: exit {code}: {problem}")
        shutil.rmtree(out, ignore_errors=True)


# -- SIGKILLed runs ----------------------------------------------------------------------------------


def _drive(command, env, kill_at=None, timeout=600.0) -> tuple[int | None, str, list]:
    """Run ``command``; SIGKILL its process (alone) after ``kill_at`` seconds if it is still running.
    Returns (exit status or None when killed, stderr's last line, PIDs of its descendants still
    running 10 s after it ended — killed here)."""
    seen: dict = {}
    with tempfile.TemporaryFile() as err:
        driver = subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=err)
        start, killed = time.monotonic(), False
        while driver.poll() is None:
            seen.update(descendants(driver.pid))
            elapsed = time.monotonic() - start
            if kill_at is not None and elapsed >= kill_at:
                os.kill(driver.pid, signal.SIGKILL)
                killed = True
                break
            if elapsed > timeout:
                os.kill(driver.pid, signal.SIGKILL)
                break
            time.sleep(0.05)
        driver.wait()
        err.seek(0)
        lines = err.read().decode(errors="replace").strip().splitlines()
    deadline = time.monotonic() + 10
    while alive(seen) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = alive(seen)
    for pid in left:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
    return (None if killed else driver.returncode), (lines[-1][:200] if lines else ""), left


def _sigkills(n, quick, rng, tmp, lib, reference, counts, bad):
    try:
        import ray  # noqa: F401
    except ImportError:
        has_ray = False
    else:
        has_ray = True
    env = {**os.environ, "BRDFSCALE_COMPILATION_CACHE": os.path.join(tmp, "cache"), "BRDFSCALE_PROGRESS": "0"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, (ROOT, env.get("PYTHONPATH"))))
    command = [sys.executable, "-m", "brdfscale", "fit-library", lib, *ARGS]
    executors = [("process", [])] + ([("ray", ["--workers", "2"])] if has_ray and not quick else [])
    duration = {"process": 2.2}  # quick: killed early (start-up, index), the rerun then does all the work
    for name, extra in executors if not quick else ():  # an uninterrupted run of each: its duration, results
        out = os.path.join(tmp, f"uninterrupted-{name}")
        t0 = time.monotonic()
        code, line, left = _drive([*command, "--out", out, *extra], env)
        duration[name] = time.monotonic() - t0
        problem = _complete(out, reference) if code == 0 else f"exit {code}: {line}"
        if problem or left:
            raise RuntimeError(f"the uninterrupted {name} run is not the reference: {problem or f'{left} left'}")
        shutil.rmtree(out, ignore_errors=True)
    for k in range(n):
        name, extra = executors[k % len(executors)]
        out = os.path.join(tmp, f"killed-{k}")
        when = rng.uniform(0.0, 0.9 * duration[name])
        counts["tried"] += 1
        code, line, left = _drive([*command, "--out", out, *extra], env, kill_at=when)
        what = f"sigkill_fit_library: {name}, killed at {when:.2f} s"
        if code is not None and code != 0:
            counts["bad"] += 1
            bad.append(f"{what}: it ended first with exit {code}: {line}")
            continue
        code, line, left_again = _drive([*command, "--out", out, *extra], env)
        problem = (_complete(out, reference) if code == 0 else f"rerun exit {code}: {line}") or (
            f"{len(left)} process(es) of the killed run left after 10 s" if left else None
        )
        if problem or left_again:
            counts["bad"] += 1
            bad.append(f"{what}: {problem or f'{len(left_again)} process(es) of the rerun left'}")
        else:
            counts["same"] += 1
        shutil.rmtree(out, ignore_errors=True)


def _write_library(directory: str, n: int, seed: int) -> None:
    """Materials 0 … n−1 of tests/helpers.py's synthetic library (their truths), all of one small
    layout (16 px, one image per scale) so that one compiled fit serves them all."""
    from brdfscale import exr, fitting
    from tests.helpers import library_truth, SCALES

    os.makedirs(directory)
    for i in range(n):
        mset = fitting.simulate(
            fitting.ParametricModel(), library_truth(i, seed), SCALES, size=16, extent=0.5, noise=0.02, seed=i
        )
        exr.write_measurements(os.path.join(directory, f"material_{i:03d}.exr"), mset)


def run(quick: bool, seed: int = 0, directory: str | None = None) -> dict:
    """The family's trials (module docstring): ``{"kinds": {kind: counts}, "bad_examples": [...]}``."""
    import jax

    jax.config.update("jax_enable_x64", True)
    rng = random.Random(seed)
    counts = _fuzz_common.tally(KINDS)
    bad: list = []
    with tempfile.TemporaryDirectory(dir=directory, prefix="fuzz-library-") as tmp:
        lib, ref = os.path.join(tmp, "lib"), os.path.join(tmp, "reference")
        _write_library(lib, 2 if quick else 3, seed)
        code, out, err = _fuzz_common.in_process(["fit-library", lib, "--out", ref, *ARGS])
        if code != 0:
            raise RuntimeError(f"the reference library fit failed (exit {code}): {out}{err}")
        reference = _results(ref, sorted(n for n in os.listdir(os.path.join(ref, "materials")) if n[0] != "."))
        _damaged_indices(6 if quick else 64, rng, tmp, lib, ref, reference, counts["damaged_index"], bad)
        _sigkills(1 if quick else 22, quick, rng, tmp, lib, reference, counts["sigkill_fit_library"], bad)
    return {"kinds": counts, "bad_examples": bad[:20]}


if __name__ == "__main__":
    sys.exit(_fuzz_common.main(run, __doc__))
