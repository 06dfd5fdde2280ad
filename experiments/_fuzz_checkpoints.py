"""Fuzz family ``checkpoints`` (issue 34): corrupted checkpoints of fitting.sample and SIGKILLed ``brdfscale fit``.

Corruptions. The chain of the linear-Gaussian posterior (tests/helpers.py) is sampled with a
checkpoint by emcee and by NUTS (10 steps per chunk) and stopped after 2 chunks, as a killed run
is; each mutant is a copy of that file damaged as a disk, a copy or a careless hand would
between the kill and the rerun, and the rerun — ``fitting.sample`` with the uninterrupted run's
arguments — is judged:

* ``bit_flip`` — one bit flipped, half of the time inside the stored chunks of the chain, its
  log-densities and the sampler's state (where HDF5 put them), else anywhere in the file;
* ``zero_block`` — one 4 KiB-aligned block of the file zeroed;
* ``nan_step`` — the eight bytes of one stored value of the chain or of log_prob set to NaN;
* ``truncate`` — the file cut at a random length.

``refused`` = :class:`brdfscale.MeasurementFileError` or :class:`brdfscale.InvalidInputError`
with a one-line message — and where the message offers :func:`fitting.rewind_checkpoint`,
the rewound file must then resume to the uninterrupted run's chain bit for bit, else the trial
is bad; ``same`` = the rerun returns the uninterrupted run's chain, log-densities and statistics
bit for bit (the damage hit bytes that carry nothing, e.g. free space); ``bad`` = anything else
(a changed result, a foreign exception).

``sigkill_fit``. ``brdfscale fit`` (emcee, a tiny parametric measurement set) is run once
uninterrupted; then, per trial, a fresh run into a new directory is SIGKILLed at a random
moment of its run time (uniform over 5–100 % of the uninterrupted run's wall time: during the
fit, the sampling, the checkpoint's writes or the report) and the same command is run again
without ``--force``. ``same`` = the rerun's exit status and fit.json (its timings and own paths
aside) are the uninterrupted run's, and its chain equal; ``refused`` = the rerun exits 2 or 3 with
one line; ``bad`` = anything else.

``python -m experiments._fuzz_checkpoints [--quick] [--json PATH]`` runs the family alone
(experiments/fuzz_robustness.py runs it with the others).
"""

import os
import random
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np

from experiments import _fuzz_common
from tests.references.damage import chunk_extents, same_samples


KINDS = ("bit_flip", "zero_block", "nan_step", "truncate")
CHUNK = 10
_SAMPLERS = ("emcee", "nuts")


def _sampler_args(name: str):
    from brdfscale import fitting

    if name == "emcee":
        return dict(sampler=fitting.Emcee(walkers=8), steps=40, chunk=CHUNK, seed=3, progress=False)
    return dict(sampler=fitting.NUTS(warmup=20), steps=20, chunk=CHUNK, seed=3, progress=False)


def _linear():
    import jax

    jax.config.update("jax_enable_x64", True)
    from brdfscale import fitting
    from tests.helpers import Linear, linear_measurements

    data = fitting.Dataset.from_measurements(linear_measurements())
    return fitting.Problem(Linear(), data), fitting.fit(Linear(), data, starts=1)


def _regions(path) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """(offset, size) of every stored HDF5 chunk of the data and state datasets; and of chain/log_prob only."""
    extents = chunk_extents(path)
    return [r for rows in extents.values() for r in rows], extents["chain"] + extents["log_prob"]


def _mutate(kind: str, data: bytes, regions, values, rng: random.Random) -> bytes:
    buf = bytearray(data)
    if kind == "bit_flip":
        if rng.random() < 0.5:
            offset, size = rng.choice(regions)
            i = offset + rng.randrange(size)
        else:
            i = rng.randrange(len(buf))
        buf[i] ^= 1 << rng.randrange(8)
    elif kind == "zero_block":
        start = rng.randrange(-(-len(buf) // 4096)) * 4096
        buf[start : start + 4096] = bytes(len(buf[start : start + 4096]))
    elif kind == "nan_step":
        offset, size = rng.choice(values)
        i = offset + 8 * rng.randrange(size // 8)
        buf[i : i + 8] = struct.pack("<d", float("nan"))
    else:  # truncate
        del buf[rng.randrange(len(buf)) :]
    return bytes(buf)


def _corruptions(n_per_kind: int, samplers, tmp: str, seed: int, tally, bad) -> None:
    import brdfscale
    from brdfscale import fitting

    problem, res = _linear()
    rng = random.Random(seed)
    for name in samplers:
        kw = _sampler_args(name)
        reference = fitting.sample(problem, res, **kw)
        partial = os.path.join(tmp, f"{name}-partial.h5")
        fitting.sample(problem, res, checkpoint=partial, **{**kw, "steps": 2 if name == "nuts" else 20})
        original = open(partial, "rb").read()
        regions, values = _regions(partial)
        for kind in KINDS:
            for trial in range(n_per_kind):
                mutant = os.path.join(tmp, f"{name}-{kind}-{trial}.h5")
                with open(mutant, "wb") as f:
                    f.write(_mutate(kind, original, regions, values, rng))
                what = f"{name} {kind} #{trial}"
                try:
                    result = fitting.sample(problem, res, checkpoint=mutant, **kw)
                except (brdfscale.MeasurementFileError, brdfscale.InvalidInputError) as err:
                    message = str(err)
                    outcome = "refused"
                    if "\n" in message:
                        outcome, why = "bad", f"{what}: a message of several lines: {message[:200]}"
                    elif "rewind_checkpoint" in message:
                        try:
                            fitting.rewind_checkpoint(mutant)
                            again = fitting.sample(problem, res, checkpoint=mutant, **kw)
                            if not same_samples(again, reference):
                                outcome, why = "bad", f"{what}: rewound and resumed, the chain differs"
                        except Exception as exc:  # noqa: BLE001 — the study records what escaped
                            outcome, why = "bad", f"{what}: rewind failed: {type(exc).__name__}: {exc}"[:300]
                except Exception as exc:  # noqa: BLE001
                    outcome, why = "bad", f"{what}: foreign {type(exc).__name__}: {exc}"[:300]
                else:
                    outcome = "same" if same_samples(result, reference) else "bad"
                    why = f"{what}: resumed into a different chain, silently"
                tally[kind]["tried"] += 1
                tally[kind][outcome] += 1
                if outcome == "bad":
                    bad.append(why)
                os.remove(mutant)


def _measurements(path: str) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    from tests.helpers import write_sampled_set

    write_sampled_set(path)


def _fit(measurements: str, out: str, env: dict, kill_after: float | None = None):
    """``brdfscale fit`` (emcee, tiny) into ``out``: (exit status, stdout, stderr, wall seconds);
    SIGKILLed after ``kill_after`` seconds when given (exit status then None)."""
    from tests.helpers import sampled_fit_argv

    argv = [sys.executable, "-m", "brdfscale", *sampled_fit_argv(measurements, out, steps=60)]
    start = time.perf_counter()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if kill_after is None:
        out_text, err_text = proc.communicate()
        return proc.returncode, out_text, err_text, time.perf_counter() - start
    try:
        out_text, err_text = proc.communicate(timeout=kill_after)
        return proc.returncode, out_text, err_text, time.perf_counter() - start  # finished first
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        out_text, err_text = proc.communicate()
        return None, out_text, err_text, time.perf_counter() - start


def _chain(out: str):
    import h5py

    with h5py.File(os.path.join(out, "chain.h5"), "r") as f:
        return f["chain"][()]


def _sigkills(n: int, tmp: str, seed: int, tally, bad, refused, warm: bool = True) -> None:
    rng = random.Random(seed + 1)
    measurements = os.path.join(tmp, "m.exr")
    _measurements(measurements)
    env = {
        **os.environ,
        "MPLBACKEND": "Agg",
        "BRDFSCALE_PROGRESS": "0",
        "BRDFSCALE_COMPILATION_CACHE": os.path.join(tmp, "jax-cache"),
    }
    reference_dir = os.path.join(tmp, "reference")
    if warm:  # fills the compilation cache, as a user's first run does: the reference's wall time is a rerun's
        _fit(measurements, os.path.join(tmp, "warm"), env)
    status, _, err, wall = _fit(measurements, reference_dir, env)
    if status not in (0, 5, 6, 7):
        bad.append(f"sigkill_fit: the uninterrupted run failed (exit {status}): {err.strip()[-200:]}")
        tally["sigkill_fit"]["tried"] += 1
        tally["sigkill_fit"]["bad"] += 1
        return
    from tests.helpers import comparable_report

    reference, reference_chain = comparable_report(reference_dir), _chain(reference_dir)
    for trial in range(n):
        out = os.path.join(tmp, f"killed-{trial}")
        after = rng.uniform(0.05, 1.0) * wall
        killed, _, _, _ = _fit(measurements, out, env, kill_after=after)
        what = f"sigkill_fit #{trial} (killed at {after:.1f} s of {wall:.1f} s)"
        code, out_text, err_text, _ = _fit(measurements, out, env)
        lines = [line for line in err_text.strip().splitlines() if line.strip()]
        if killed is not None:
            what += " (it finished before the kill)"
        if code == status and os.path.exists(os.path.join(out, "fit.json")):
            same = comparable_report(out) == reference and np.array_equal(_chain(out), reference_chain)
            outcome = "same" if same else "bad"
            why = f"{what}: the rerun's report differs from the uninterrupted run's"
        elif code in (2, 3) and len(lines) == 1 and "Traceback" not in err_text:
            outcome, why = "refused", ""
            refused.append(f"{what}: exit {code}: {lines[0][:250]}")
        else:
            outcome = "bad"
            why = f"{what}: rerun exit {code}: {' | '.join(lines)[-250:]}"
        tally["sigkill_fit"]["tried"] += 1
        tally["sigkill_fit"][outcome] += 1
        if outcome == "bad":
            bad.append(why)
        shutil.rmtree(out, ignore_errors=True)


def run(quick: bool, seed: int = 0, directory: str | None = None) -> dict:
    """The family's tallies (module docstring): ``quick`` — 3 mutants per kind on emcee's
    checkpoint and 1 SIGKILL; else 15 per kind and sampler (120 corruptions) and 20 SIGKILLs."""
    tally = _fuzz_common.tally(KINDS + ("sigkill_fit",))
    bad: list[str] = []
    refused: list[str] = []  # what the refused reruns said (not part of the family's interface; kept for reading)
    tmp = tempfile.mkdtemp(prefix="fuzz-checkpoints-", dir=directory)
    try:
        _corruptions(3 if quick else 15, ("emcee",) if quick else _SAMPLERS, tmp, seed, tally, bad)
        _sigkills(1 if quick else 20, tmp, seed, tally, bad, refused, warm=not quick)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"kinds": tally, "bad_examples": bad[:20], "refused_examples": refused[:20]}


if __name__ == "__main__":
    sys.exit(_fuzz_common.main(run, __doc__))
