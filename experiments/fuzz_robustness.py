"""Reliability fuzzing (issue 16): damaged measurement files and hostile command lines.

Files. A small valid measurement set (two parts, RGB values, σ, mask, metadata) and a lobe
table are written, then mutated; each mutant is read with :func:`brdfscale.exr.read_measurements`
(or ``read_lobe_table``). Kinds of mutation:

* ``bit_flip`` / ``byte_set`` / ``truncate`` / ``insert`` — raw bytes anywhere in the file;
* ``attribute`` — one ``brdfscale.*`` attribute rewritten with a plausible other value (μ × 2,
  another extent or incident direction, metadata changed) keeping the stored digest;
* ``channel`` — the ``sigma.*`` or ``mask`` channel removed, or an unlisted channel added;
* ``crafted`` — a consistently re-sealed file (digest recomputed, as a buggy or hostile
  writer would) whose metadata JSON is hostile: nested 10 000 deep, a 5 000-digit integer,
  NaN, 17 MiB, a non-object; or whose attribute strings are not UTF-8.

Outcomes: ``refused`` (:class:`brdfscale.MeasurementFileError`), ``same`` (read back identical
to the original: the mutation hit bytes that carry no data, e.g. the part name), and the two
failures ``changed`` (data read back different, silently) and ``foreign`` (any other exception).

Command lines. Templates of every subcommand, mutated: an option's value replaced by one of a
pool of hostile values (negative, 0, 1e300, nan, inf, '', a 22-digit integer, text, …), an
option repeated, abbreviated, unknown, a required argument dropped. Each command line's
expected verdict follows from the documented domains (``--help``): valid ones must exit 0,
invalid ones exit 2 with a one-line message; fit/demo/example lines are generated invalid
only (a valid one would run a fit). Failures: ``traceback`` (stderr holds a Python traceback),
``accepted_nonsense`` (invalid but exit 0), ``refused_valid``, ``wrong_status``.

Families (issue 34), each in its own module ``experiments/_fuzz_<family>.py`` exposing
``run(quick, seed, directory) -> {"kinds": {kind: {tried, refused, same, bad}}, "bad_examples": [...]}``
and one command line (experiments/_fuzz_common.py: the tallies, the in-process runs of
``brdfscale``, ``--quick --seed --json``) (:data:`FAMILIES`): damaged instrument files and
hostile heights (``topography``), corrupted checkpoints and SIGKILLed fits (``checkpoints``),
full disks for every command (``disk``), damaged library indices and SIGKILLed ``fit-library``
runs (``library``), hostile σ and the σ-scale invariance of the optimum (``numbers``). "bad" is
any outcome that is neither the library's own refusal nor the undamaged result.

Run: ``flock /tmp/brdfscale-bench.lock python -m experiments.fuzz_robustness`` (5 000 file
mutants, 300 command lines, every family at its full size) →
experiments/results/fuzz_robustness/fuzz_robustness.json; ``--quick`` for the smoke version
(tests/test_experiments_smoke.py); ``--families checkpoints,disk`` runs only those families
and keeps the other parts of the committed JSON.
"""

import argparse
import collections
import contextlib
import importlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import brdfscale as bs
from brdfscale import exr
from brdfscale.exr import _format
from experiments._studies import study_dir, write_results
from tests.helpers import HOSTILE, rewrite_exr, run_command, same_set, sample_set, SYNTH_DOMAINS


# -- files -----------------------------------------------------------------------------------


def sample_table() -> exr.LobeTable:
    v = np.random.default_rng(8).random((2, 7, 7)) + 0.01
    return exr.LobeTable(np.array([1.0, 4.0]), 0.3, v, {"source": "fuzz"})


def same_table(a: exr.LobeTable, b: exr.LobeTable) -> bool:
    return (
        np.array_equal(a.scales, b.scales)
        and a.extent == b.extent
        and np.array_equal(a.values, b.values)
        and a.metadata == b.metadata
    )


@contextlib.contextmanager
def quiet_stderr():
    """OpenEXR's C++ layer prints warnings on file descriptors 1 and 2 for damaged pixel data."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        os.dup2(null.fileno(), 2)
        try:
            yield
        finally:
            for fd, copy in zip((1, 2), saved):
                os.dup2(copy, fd)
                os.close(copy)


def _attribute_edits(kind: str):
    P = _format.PREFIX
    edits = [
        lambda i, h, c: h.__setitem__(P + "mu", h[P + "mu"] * 2),
        lambda i, h, c: h.__setitem__(P + "extent", h[P + "extent"] * 1.5),
        lambda i, h, c: (
            h.__setitem__(P + "checksums", h[P + "checksums"])
            if i
            else h.__setitem__(P + "metadata", json.dumps({**json.loads(h[P + "metadata"]), "extra": 1}))
        ),
        lambda i, h, c: h.__setitem__(P + "domain", h[P + "domain"]),  # no change: must read identically
    ]
    if kind == "measurement_set":
        edits.append(lambda i, h, c: h.__setitem__(P + "incident", np.array([0.0, 0.6, 0.8])))
    return edits


def _channel_edits(kind: str):
    edits = [lambda i, h, c: c.__setitem__("extra", np.zeros_like(next(iter(c.values()))))]
    if kind == "measurement_set":
        edits += [lambda i, h, c: c.pop("mask"), lambda i, h, c: [c.pop(k) for k in list(c) if k.startswith("sigma")]]
    return edits


def _crafted(rng, kind: str):
    P = _format.PREFIX
    deep = "[" * 10_000 + "]" * 10_000
    bad_json = [
        f'{{"a": {deep}}}',
        '{"n": ' + "7" * 5000 + "}",
        '{"x": NaN}',
        "[1, 2]",
        '{"big": "' + "x" * (17 * 2**20) + '"}',
    ]
    choice = rng.integers(len(bad_json))
    return lambda i, h, c: h.__setitem__(P + "metadata", bad_json[choice]) if i == 0 else None


def mutate_file(kind_of_mutation: str, data: bytes, src: str, dst: str, rng, file_kind: str) -> None:
    if kind_of_mutation in ("bit_flip", "byte_set", "truncate", "insert"):
        b = bytearray(data)
        i = int(rng.integers(len(b)))
        if kind_of_mutation == "bit_flip":
            b[i] ^= 1 << int(rng.integers(8))
        elif kind_of_mutation == "byte_set":
            b[i] = int(rng.integers(256))
        elif kind_of_mutation == "truncate":
            b = b[:i]
        else:
            b[i:i] = bytes(rng.integers(0, 256, int(rng.integers(1, 9))).astype(np.uint8))
        Path(dst).write_bytes(bytes(b))
    elif kind_of_mutation == "attribute":
        edits = _attribute_edits(file_kind)
        rewrite_exr(src, dst, edits[int(rng.integers(len(edits)))])
    elif kind_of_mutation == "channel":
        edits = _channel_edits(file_kind)
        edit = edits[int(rng.integers(len(edits)))]
        part = int(rng.integers(2))
        rewrite_exr(src, dst, lambda i, h, c: edit(i, h, c) if i == part else None)
    elif kind_of_mutation == "crafted":
        rewrite_exr(src, dst, _crafted(rng, file_kind), reseal=True)
        if rng.random() < 0.4:  # a non-UTF-8 byte inside an attribute string, in place
            b = bytearray(Path(dst).read_bytes())
            at = b.find(b"half_slope")
            b[at + int(rng.integers(10))] = 0xFF
            Path(dst).write_bytes(bytes(b))
    else:
        raise ValueError(kind_of_mutation)


FILE_KINDS = ("bit_flip", "byte_set", "truncate", "insert", "attribute", "channel", "crafted")


def fuzz_files(n: int, seed: int = 0, directory: str | None = None) -> dict:
    """``n`` mutants (spread over :data:`FILE_KINDS` and the two file kinds); tallies by kind."""
    rng = np.random.default_rng(seed)
    tmp = tempfile.mkdtemp(dir=directory)
    originals = {}
    for file_kind, obj, write, read, same in (
        ("measurement_set", sample_set(), exr.write_measurements, exr.read_measurements, same_set),
        ("lobe_table", sample_table(), exr.write_lobe_table, exr.read_lobe_table, same_table),
    ):
        path = os.path.join(tmp, f"{file_kind}.exr")
        write(path, obj)
        originals[file_kind] = (path, Path(path).read_bytes(), read(path), read, same)
    tally = collections.defaultdict(collections.Counter)
    failures = []
    dst = os.path.join(tmp, "mutant.exr")
    for t in range(n):
        kind = FILE_KINDS[t % len(FILE_KINDS)]
        file_kind = ("measurement_set", "lobe_table")[(t // len(FILE_KINDS)) % 2]
        src, data, ref, read, same = originals[file_kind]
        mutate_file(kind, data, src, dst, rng, file_kind)
        with quiet_stderr():
            try:
                out = read(dst)
                outcome = "same" if same(out, ref) else "changed"
            except bs.MeasurementFileError:
                outcome = "refused"
            except Exception as err:  # noqa: BLE001 — what the fuzzing is looking for
                outcome = "foreign"
                failures.append({"kind": kind, "file": file_kind, "error": f"{type(err).__name__}: {err}"[:300]})
        if outcome == "changed":
            failures.append({"kind": kind, "file": file_kind, "error": "data changed silently"})
        tally[kind][outcome] += 1
    rows = {
        k: {
            "tried": sum(c.values()),
            "refused": c["refused"],
            "same": c["same"],
            "changed": c["changed"],
            "foreign": c["foreign"],
        }
        for k, c in tally.items()
    }
    return {
        "mutants": n,
        "by_kind": rows,
        "failures": failures[:50],
        "bad": sum(r["changed"] + r["foreign"] for r in rows.values()),
    }


# -- command lines -----------------------------------------------------------------------------


def _invalid_for(option: str, text: str) -> bool:
    """Invalid values used for fit/demo lines (so that no fit runs)."""
    domain = {
        "--steps": (0, 10**6),
        "--starts": (1, 256),
        "--walkers": (2, 4096),
        "--seed": (0, 2**32 - 1),
        "--base-nodes": (3, 41),
        "--knots": (2, 64),
        "--max-steps": (1, 10**5),
    }.get(option)
    try:
        if domain is None:  # --default-sigma: positive finite ≤ 1e30
            x = float(text)
            return not (x == x and 0 < x <= 1e30)
        x = int(text)
        return not domain[0] <= x <= domain[1]
    except ValueError:
        return True


def command_lines(n: int, rng, tmp: str, measurements: str) -> list[tuple[list[str], bool]]:
    """``n`` (argv, valid) pairs."""
    out = []
    synth_base = ["synth", "gaussian", "--size", "16", "--pixels", "5", "--scales", "2,4"]
    fit_options = [
        "--steps",
        "--starts",
        "--walkers",
        "--seed",
        "--base-nodes",
        "--knots",
        "--max-steps",
        "--default-sigma",
    ]
    k = 0
    while len(out) < n:
        k += 1
        r = rng.random()
        target = os.path.join(tmp, f"o{k}.exr")
        if r < 0.35:  # synth with one option mutated (valid or not, per the documented domain)
            option = sorted(SYNTH_DOMAINS)[int(rng.integers(len(SYNTH_DOMAINS)))]
            value = HOSTILE[int(rng.integers(len(HOSTILE)))]
            argv = list(synth_base)
            if option in argv:
                i = argv.index(option)
                del argv[i : i + 2]
            argv += ["--out", target, option, value]
            out.append((argv, SYNTH_DOMAINS[option](value)))
        elif r < 0.7:  # fit / demo with an invalid value
            cmd = "fit" if rng.random() < 0.7 else "demo"
            options = fit_options if cmd == "fit" else ["--steps", "--seed"]
            option = options[int(rng.integers(len(options)))]
            candidates = [v for v in HOSTILE if _invalid_for(option, v)]
            value = candidates[int(rng.integers(len(candidates)))]
            argv = ([cmd, measurements] if cmd == "fit" else [cmd]) + [
                "--out",
                os.path.join(tmp, f"d{k}"),
                option,
                value,
            ]
            out.append((argv, False))
        elif r < 0.85:  # structural: repeated, abbreviated, unknown option, missing argument
            s = int(rng.integers(5))
            argv = {
                0: ["fit", measurements, "--out", os.path.join(tmp, f"d{k}"), "--force", "--force"],
                1: ["fit", measurements, "--out", os.path.join(tmp, f"d{k}"), "--walker", "8"],
                2: ["synth", "gaussian", "--out", target, "--pix", "5"],
                3: ["fit", "--out", os.path.join(tmp, f"d{k}")],
                4: ["fit", measurements, "--out", os.path.join(tmp, f"d{k}"), "--fix", "mu_c=1", "--fix", "mu_c=2"],
            }[s]
            out.append((argv, False))
        else:  # paths: empty, existing file, directory as a file, missing input, a device
            s = int(rng.integers(6))
            existing = os.path.join(tmp, "existing_file")
            Path(existing).touch()
            argv = {
                0: ["demo", "--out", ""],
                1: ["demo", "--out", existing],
                2: ["example", "--out", ""],
                3: ["synth", "gaussian", "--out", tmp],
                4: ["info", os.path.join(tmp, "missing.exr")],
                5: ["info", "/dev/null"],
            }[s]
            out.append((argv, False))
    return out


def fuzz_command_lines(n: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    tmp = tempfile.mkdtemp()
    measurements = os.path.join(tmp, "m.exr")
    exr.write_measurements(measurements, sample_set())
    tally = collections.defaultdict(collections.Counter)
    failures = []
    for argv, valid in command_lines(n, rng, tmp, measurements):
        code, err = run_command(argv)
        kind = argv[0]
        if "Traceback" in err:
            outcome = "traceback"
        elif valid:
            outcome = "ok" if code == 0 else "refused_valid"
        elif code == 0:
            outcome = "accepted_nonsense"
        elif code == 2:
            outcome = "refused"
        else:
            outcome = "wrong_status"
        tally[kind][outcome] += 1
        if outcome not in ("ok", "refused"):
            failures.append({"argv": argv, "status": code, "stderr": err[-400:]})
    rows = {
        k: {
            "tried": sum(c.values()),
            **{o: c[o] for o in ("ok", "refused", "traceback", "accepted_nonsense", "refused_valid", "wrong_status")},
        }
        for k, c in sorted(tally.items())
    }
    bad = sum(r["traceback"] + r["accepted_nonsense"] + r["refused_valid"] + r["wrong_status"] for r in rows.values())
    return {"command_lines": n, "by_command": rows, "failures": failures[:50], "bad": bad}


# -- families (issue 34) ---------------------------------------------------------------------

#: The families' modules, ``experiments/_fuzz_<family>.py``, in the order of the table.
FAMILIES = ("topography", "checkpoints", "disk", "library", "numbers")


def fuzz_family(family: str, quick: bool, seed: int = 0, directory: str | None = None) -> dict:
    """One family's tallies: ``{"kinds": {kind: {tried, refused, same, bad}}, "bad_examples", "bad",
    "wall_seconds"}``."""
    module = importlib.import_module(f"experiments._fuzz_{family}")
    start = time.perf_counter()
    result = dict(module.run(quick, seed=seed, directory=directory))
    result["bad"] = sum(int(r["bad"]) for r in result["kinds"].values())
    result["wall_seconds"] = time.perf_counter() - start
    return result


def page(payload: dict) -> str:
    """The tables of docs/robustness.md (generated block) from the study's JSON."""
    from experiments._bench import table

    f, c = payload["files"], payload["cli"]
    rows = [
        [k, str(r["tried"]), str(r["refused"]), str(r["same"]), str(r["changed"]), str(r["foreign"])]
        for k, r in f["by_kind"].items()
    ]
    total = {x: sum(r[x] for r in f["by_kind"].values()) for x in ("tried", "refused", "same", "changed", "foreign")}
    rows.append(["**all**", *(f"**{total[x]}**" for x in ("tried", "refused", "same", "changed", "foreign"))])
    out = [
        f"{f['mutants']} mutated files (seed 0), {payload['machine']['date_utc']}: refused = the library's "
        "`MeasurementFileError`; same = read back identical (the bytes hit carry no data, e.g. a part name); "
        "changed and foreign are the failures.",
        "",
        table(["mutation", "tried", "refused", "same", "changed", "foreign"], rows),
        "",
    ]
    keys = ("ok", "refused", "traceback", "accepted_nonsense", "refused_valid", "wrong_status")
    rows = [[k, str(r["tried"]), *(str(r[x]) for x in keys)] for k, r in c["by_command"].items()]
    out += [
        f"{c['command_lines']} command lines (seed 0): ok = valid and exit 0, refused = invalid and exit 2 "
        "with one message; the other columns are failures.",
        "",
        table(["command", "tried", *keys], rows),
    ]
    families = payload.get("families") or {}
    if families:
        keys = ("tried", "refused", "same", "bad")
        rows = [
            [family, kind, *(str(r[x]) for x in keys)]
            for family, result in families.items()
            for kind, r in result["kinds"].items()
        ]
        out += [
            "",
            "Families of issue 34 (seed 0): refused = the library's own error or documented exit status with "
            "one line; same = the undamaged result (or the command completed correctly); bad = anything else.",
            "",
            table(["family", "kind", *keys], rows),
        ]
    return "\n".join(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke version: 140 file mutants, 40 command lines")
    parser.add_argument("--files", type=int, default=5000)
    parser.add_argument("--commands", type=int, default=300)
    parser.add_argument("--out", default=None, help="results directory (default experiments/results/fuzz_robustness)")
    parser.add_argument(
        "--families",
        default=None,
        help=f"comma-separated families to run ({', '.join(FAMILIES)}); the file and command-line parts and the "
        "other families are then kept from the committed JSON",
    )
    args = parser.parse_args(argv)
    n_files, n_commands = (140, 40) if args.quick else (args.files, args.commands)
    directory = study_dir("fuzz_robustness", args.out)
    start = time.perf_counter()
    if args.families is None:
        chosen = FAMILIES
        files_result = fuzz_files(n_files)
        print(f"files: {n_files} mutants, bad {files_result['bad']}: " + json.dumps(files_result["by_kind"]))
        cli_result = fuzz_command_lines(n_commands)
        print(f"command lines: {n_commands}, bad {cli_result['bad']}: " + json.dumps(cli_result["by_command"]))
        families = {}
    else:
        chosen = tuple(f.strip() for f in args.families.split(",") if f.strip())
        unknown = sorted(set(chosen) - set(FAMILIES))
        if unknown:
            parser.error(f"unknown families {unknown}; the families are {', '.join(FAMILIES)}")
        committed = json.loads((Path(directory) / "fuzz_robustness.json").read_text())
        files_result, cli_result = committed["files"], committed["cli"]
        families = dict(committed.get("families") or {})
    for family in chosen:
        families[family] = fuzz_family(family, args.quick)
        print(f"{family}: bad {families[family]['bad']}: " + json.dumps(families[family]["kinds"]))
    payload = {
        "study": "fuzz_robustness",
        "quick": args.quick,
        "files": files_result,
        "cli": cli_result,
        "families": {f: families[f] for f in FAMILIES if f in families},
        "wall_seconds": time.perf_counter() - start,
    }
    path = write_results(directory, "fuzz_robustness", payload)
    print(f"wrote {path}")
    bad = files_result["bad"] + cli_result["bad"] + sum(r["bad"] for r in payload["families"].values())
    return 0 if bad == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
