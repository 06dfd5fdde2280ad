"""Checkpoints with integrity (issue 34): damage refused for every sampler, restart from the last good
chunk bit-identical, a full disk reported by the library's error, fit's report phase resumed.

The corruptions are made on the bytes of the file, where HDF5 itself stored the chunks of
``chain`` and ``log_prob`` (h5py's chunk index gives their offsets): one flipped bit, a zeroed
4 KiB block, the eight bytes of one value set to NaN — the damage a disk, a copy or a careless
hand does between a kill and the rerun. Each must be refused by ``fitting.sample`` naming the
chunk; nothing damaged is resumed into a result. A NaN written consistently (the chunk's
SHA-256 recomputed, as a buggy writer would) is refused by the NaN check on its own.

The posterior is the linear-Gaussian one of tests/helpers.py (tiny, quick to compile); the
bit-identical comparisons are against the uninterrupted run with the same arguments.
"""

import errno
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

import brdfscale
from brdfscale import fitting, InvalidInputError, MeasurementFileError, OutputWriteError
from brdfscale.choices import SAMPLE
from brdfscale.fitting import _checkpoint, _resume
from tests.helpers import (
    comparable_report,
    Linear,
    linear_measurements,
    run_command,
    sampled_fit_argv,
    write_sampled_set,
)
from tests.references.damage import chunk_extents, flip_bit, overwrite, same_samples


CHUNK = 10
SAMPLERS = {
    "emcee": dict(sampler=fitting.Emcee(walkers=8), steps=40),
    "nuts": dict(sampler=fitting.NUTS(warmup=20), steps=20),
    "hmc": dict(sampler=fitting.HMC(warmup=20), steps=20),
    "imh": dict(sampler=fitting.IMH(), steps=40),
}


@pytest.fixture(scope="module")
def linear():
    data = fitting.Dataset.from_measurements(linear_measurements())
    model = Linear()
    return fitting.Problem(model, data), fitting.fit(model, data, starts=1)


@pytest.fixture(scope="module")
def runs(linear, tmp_path_factory):
    """Per sampler: its arguments, the uninterrupted run and a complete checkpoint of it (40 steps, 4 chunks)."""
    problem, res = linear
    out = {}
    for name, kw in SAMPLERS.items():
        kw = dict(chunk=CHUNK, progress=False, seed=7, **kw)
        path = tmp_path_factory.mktemp(name) / "chain.h5"
        full = fitting.sample(problem, res, checkpoint=path, **kw)
        out[name] = (kw, full, path)
    return out


def _chunk_bytes(path, dataset: str, k: int) -> tuple[int, int]:
    """(offset, size) in the file of HDF5 chunk ``k`` of ``dataset``."""
    return chunk_extents(path)[dataset][k]


def _copy(src, tmp_path, name="c.h5"):
    dst = tmp_path / name
    shutil.copyfile(src, dst)
    return dst


# -- corruption refused, naming the chunk -----------------------------------------------------


@pytest.mark.parametrize("name", list(SAMPLERS))
def test_damaged_chunks_are_refused_for_every_sampler(linear, runs, name, tmp_path):
    problem, res = linear
    kw, full, src = runs[name]
    W, d = full.chain.shape[1:]
    for k in range(4):
        offset, size = _chunk_bytes(src, "chain", k)
        for what, damage in [
            ("bit flip", lambda p: flip_bit(p, offset + size // 2)),
            ("NaN step", lambda p: overwrite(p, offset + 8 * W * d, struct.pack("<d", float("nan")))),
            ("zeroed 4 KiB", lambda p: overwrite(p, (offset + size // 2) // 4096 * 4096, bytes(4096))),
        ]:
            path = _copy(src, tmp_path)
            damage(path)
            with pytest.raises(MeasurementFileError) as err:
                fitting.sample(problem, res, checkpoint=path, **kw)
            message = str(err.value)
            assert str(path) in message and "damaged" in message, (what, k, message)
            if what != "zeroed 4 KiB":  # a 4 KiB block may also hit HDF5's own structures: any refusal then
                assert f"chunk {k} (steps {10 * k}–{10 * k + 9}) fails its SHA-256 check" in message, (what, message)
                remedy = "rewind_checkpoint" if k else "overwrite=True"
                assert remedy in message, message
    # log_prob and statistics are covered too
    offset, size = _chunk_bytes(src, "log_prob", 1)
    path = _copy(src, tmp_path)
    overwrite(path, offset + 8, struct.pack("<d", float("nan")))
    with pytest.raises(MeasurementFileError, match=r"chunk 1 \(steps 10–19\) fails its SHA-256 check"):
        fitting.sample(problem, res, checkpoint=path, **kw)


@pytest.mark.parametrize("name", ["emcee", "nuts"])
def test_every_zeroed_4k_block_is_refused_or_harmless(linear, runs, name, tmp_path):
    """Each 4 KiB block of the file zeroed in turn — HDF5's superblock, object headers, B-trees,
    heaps, the chunks: the library's own error, or (free space, padding) the undamaged chain."""
    problem, res = linear
    kw, full, src = runs[name]
    data = open(src, "rb").read()
    outcomes = []
    for start in range(0, len(data), 4096):
        path = tmp_path / f"z{start}.h5"
        path.write_bytes(data[:start] + bytes(len(data[start : start + 4096])) + data[start + 4096 :])
        try:
            outcomes.append(
                "same" if same_samples(fitting.sample(problem, res, checkpoint=path, **kw), full) else "changed"
            )
        except (MeasurementFileError, InvalidInputError) as err:
            assert "\n" not in str(err) and str(path) in str(err)
            outcomes.append("refused")
    assert "changed" not in outcomes and outcomes.count("refused") >= len(outcomes) // 2, outcomes


@pytest.mark.parametrize("where", ["chain", "log_prob", "state"])
def test_a_consistently_sealed_nan_is_refused(linear, runs, where, tmp_path):
    """NaN written with the chunk's SHA-256 recomputed (a writer's bug, not a disk's) is refused
    by the NaN check itself."""
    problem, res = linear
    kw, _, src = runs["nuts"]
    path = _copy(src, tmp_path)
    with h5py.File(path, "r+") as f:
        if where == "state":
            f["state/position"][2, 0, 0] = np.nan
        else:
            f[where][25, 0] = np.nan  # inside chunk 2
        _reseal(f)
    with pytest.raises(MeasurementFileError, match="chunk 2 .* holds NaN or infinite values"):
        fitting.sample(problem, res, checkpoint=path, **kw)


def _reseal(f) -> None:
    """Recompute every chunk's digest from the bytes in the file (what a buggy writer might do)."""
    previous, start = f.attrs["header"], 0
    names = ["chain", "log_prob"] + [f"stats/{k}" for k in sorted(f["stats"])]
    for j, end in enumerate(f["chunks/end"][()]):
        blocks = [(n, f[n][start:end]) for n in names]
        state = {n: ds[j] for n, ds in f["state"].items()}
        previous = _checkpoint._chunk_digest(previous, int(end), blocks, state)
        f["chunks/digest"][j] = previous.encode()
        start = end


def test_header_signature_and_table_damage_are_refused(linear, runs, tmp_path):
    problem, res = linear
    kw, _, src = runs["emcee"]
    path = _copy(src, tmp_path)
    with h5py.File(path, "r+") as f:
        f["subspace/origin"][0] += 1e-12  # the sampled subspace: covered by the header digest
    with pytest.raises(MeasurementFileError, match="header .* fails its SHA-256 check.*no chunk of it can be kept"):
        fitting.sample(problem, res, checkpoint=path, **kw)
    with pytest.raises(MeasurementFileError, match="nothing of it can be kept"):
        fitting.rewind_checkpoint(path)
    path = _copy(src, tmp_path)
    with h5py.File(path, "r+") as f:
        f["chunks/digest"][3] = b"0" * 64
    with pytest.raises(MeasurementFileError, match=r"chunk 3 \(steps 30–39\) fails"):
        fitting.sample(problem, res, checkpoint=path, **kw)
    path = _copy(src, tmp_path)
    with h5py.File(path, "r+") as f:  # the table says chunk 1 ends later than it did: its digest includes the end
        f["chunks/end"][1] = 21
    with pytest.raises(MeasurementFileError, match="chunk 1 .* fails"):
        fitting.sample(problem, res, checkpoint=path, **kw)
    path = _copy(src, tmp_path)
    with h5py.File(path, "r+") as f:  # a format written before checksums: refused, not trusted
        f.attrs["format"] = "brdfscale.fitting.sample/2"
    with pytest.raises(InvalidInputError, match="earlier version.*no checksums"):
        fitting.sample(problem, res, checkpoint=path, **kw)


# -- restart from the last good chunk ------------------------------------------------------


@pytest.mark.parametrize("name", list(SAMPLERS))
def test_rewind_then_resume_gives_the_undamaged_chain(linear, runs, name, tmp_path):
    problem, res = linear
    kw, full, src = runs[name]
    path = _copy(src, tmp_path)
    assert fitting.rewind_checkpoint(path) == 40 and open(path, "rb").read() == open(src, "rb").read()  # whole: kept
    offset, size = _chunk_bytes(src, "chain", 2)
    overwrite(path, offset + 100, b"\x00\x01\x02")
    with pytest.raises(MeasurementFileError, match=r"steps before it \(0–19\) verify.*rewind_checkpoint"):
        fitting.sample(problem, res, checkpoint=path, **kw)
    assert fitting.rewind_checkpoint(path) == 20
    with h5py.File(path, "r") as f:
        assert int(f.attrs["steps_done"]) == 20 and list(f["chunks/end"][()]) == [10, 20]
    resumed = fitting.sample(problem, res, checkpoint=path, **kw)
    assert same_samples(resumed, full)
    again = fitting.sample(problem, res, checkpoint=path, **kw)  # the finished chain, read and verified
    assert same_samples(again, full)


# -- a full disk ----------------------------------------------------------------------------


def test_full_disk_before_a_chunk_is_the_librarys_error(linear, runs, tmp_path, monkeypatch):
    """Too little free space for the next chunk: OutputWriteError naming the file and the free
    space, before HDF5 writes anything; the committed chunks stay, and the rerun completes the
    undamaged chain."""
    problem, res = linear
    kw, full, src = runs["emcee"]
    path = tmp_path / "c.h5"
    calls = {"n": 0}
    original = brdfscale._files.free_space

    def shrinking(p):
        calls["n"] += 1
        return 1000 if calls["n"] > 3 else original(p)  # creation and two chunks fit; the third does not

    with monkeypatch.context() as patch:
        patch.setattr(brdfscale._files, "free_space", shrinking)
        with pytest.raises(OutputWriteError, match="disk full") as err:
            fitting.sample(problem, res, checkpoint=path, **kw)
    assert str(path) in str(err.value) and "\n" not in str(err.value)
    with h5py.File(path, "r") as f:
        assert int(f.attrs["steps_done"]) == 20
    assert same_samples(fitting.sample(problem, res, checkpoint=path, **kw), full)


def test_full_disk_inside_hdf5_is_the_librarys_error(linear, runs, tmp_path, monkeypatch):
    """ENOSPC raised by h5py itself in the middle of a chunk's write (injected at the h5py
    boundary): OutputWriteError, the file still verifies with the chunks before, the rerun
    completes bit-identically."""
    problem, res = linear
    kw, full, _ = runs["nuts"]
    path = tmp_path / "c.h5"
    commit, setitem, calls = _checkpoint._commit, h5py.Dataset.__setitem__, {"commits": 0, "writes": 0}

    def failing(self, key, value):
        calls["writes"] += 1
        if calls["writes"] == 3:  # the third dataset write of the chunk: its block half written
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return setitem(self, key, value)

    def third_fails(f, blocks, state):
        calls["commits"] += 1
        if calls["commits"] < 3:
            return commit(f, blocks, state)
        with monkeypatch.context() as patch:
            patch.setattr(h5py.Dataset, "__setitem__", failing)
            return commit(f, blocks, state)

    with monkeypatch.context() as patch:
        patch.setattr(_checkpoint, "_commit", third_fails)
        with pytest.raises(OutputWriteError, match=r"not written: disk full \(No space left on device\)") as err:
            fitting.sample(problem, res, checkpoint=path, **kw)
    assert str(path) in str(err.value) and "committed before this write are kept" in str(err.value)
    with h5py.File(path, "r") as f:
        assert int(f.attrs["steps_done"]) == 20
    assert same_samples(fitting.sample(problem, res, checkpoint=path, **kw), full)


# -- fit's report phase ---------------------------------------------------------------------


def _report_dir(tmp_path, src, files=("corner.png",), fit_json=None):
    out = tmp_path / "out"
    out.mkdir()
    shutil.copyfile(src, out / "chain.h5")
    for name in files:
        (out / name).write_bytes(b"\x89PNG partial")
    if fit_json is not None:
        (out / "fit.json").write_text(fit_json)
    return out


def test_resume_report_decides_from_the_report_and_the_verified_chain(runs, tmp_path):
    _, _, src = runs["nuts"]  # 20 warm-up steps + 20 draws
    fresh = tmp_path / "fresh"
    assert fitting.resume_report(fresh, checkpoint=fresh / "chain.h5", steps=20) is None and fresh.is_dir()
    out = _report_dir(tmp_path, src)
    line = fitting.resume_report(out, checkpoint=out / "chain.h5", steps=20)
    assert line is not None and "resuming the report" in line and "40 steps, every chunk verified" in line
    assert "\n" not in line
    with pytest.raises(InvalidInputError, match="holds 40 of the 50 steps asked"):
        fitting.resume_report(out, checkpoint=out / "chain.h5", steps=30)
    # steps None (a command run with --steps not given): the recorded sampler's own default, NUTS's 1000 draws
    with pytest.raises(InvalidInputError, match=f"holds 40 of the {20 + SAMPLE.gradient_steps} steps asked"):
        fitting.resume_report(out, checkpoint=out / "chain.h5", steps=None)
    (out / "fit.json").write_text('{"parameters": {}')  # cut short: not a finished report
    assert fitting.resume_report(out, checkpoint=out / "chain.h5", steps=20) is not None
    (out / "fit.json").write_text("{}")  # a JSON object without a report's sections: not a finished report
    assert "fit.json is incomplete (no model, data" in fitting.resume_report(out, checkpoint=out / "chain.h5", steps=20)
    finished = {key: {} for key in _resume.REPORT_KEYS} | {"figures": ["corner.png", "fit.png"], "tables": []}
    (out / "fit.json").write_text(json.dumps(finished))  # lists a figure that is not there: not finished either
    line = fitting.resume_report(out, checkpoint=out / "chain.h5", steps=20)
    assert line is not None and "fit.png, listed in fit.json, is missing" in line
    (out / "fit.png").write_bytes(b"\x89PNG")  # every section, every file it lists: a finished report, refused
    assert fitting.report_problem(out) is None
    with pytest.raises(InvalidInputError, match="already holds corner.png, .*fit.json"):
        fitting.resume_report(out, checkpoint=out / "chain.h5", steps=20)
    os.remove(out / "fit.png")
    assert fitting.resume_report(out, True, checkpoint=out / "chain.h5", steps=20) is None  # overwrite
    os.remove(out / "fit.json")
    offset, _ = _chunk_bytes(out / "chain.h5", "chain", 3)
    overwrite(out / "chain.h5", offset, b"\xff")
    with pytest.raises(MeasurementFileError, match="chunk 3 .* fails its SHA-256"):
        fitting.resume_report(out, checkpoint=out / "chain.h5", steps=20)
    os.remove(out / "chain.h5")
    with pytest.raises(InvalidInputError, match="already holds corner.png.*no chain beside them"):
        fitting.resume_report(out, checkpoint=out / "chain.h5", steps=20)
    assert "samples nothing" in fitting.resume_report(out, checkpoint=None, steps=0)


def _measurements(tmp_path) -> str:
    return write_sampled_set(tmp_path / "m.exr")


def _fit_argv(measurements, out) -> list[str]:
    return sampled_fit_argv(measurements, out, steps=30)


def _without_timing(doc: dict) -> dict:
    doc = json.loads(json.dumps(doc))
    (doc.get("mcmc") or {}).pop("timing_s", None)
    return doc


@pytest.mark.slow  # ~15–60 s on 2 cores (two fits of the parametric model through the command)
def test_fit_command_resumes_an_interrupted_report(tmp_path, monkeypatch):
    """The report's files deleted or cut short after a complete run (what a kill or a full disk
    during the report leaves): the rerun without --force says so in one line, does not sample
    again (chain.h5 unchanged), and writes the report of the uninterrupted run. A full disk
    while the chain is written exits 8 with one line; the rerun completes."""
    measurements = _measurements(tmp_path)
    out = tmp_path / "out"
    argv = _fit_argv(measurements, out)
    with monkeypatch.context() as patch:
        patch.setattr(brdfscale._files, "free_space", lambda p: 4096)
        code, err = run_command(argv)
    assert code == 8 and "not written: disk full" in err and len(err.strip().splitlines()) == 1, err
    status, err = run_command(argv)
    assert status in (0, 5, 6, 7), err  # the report is complete (5–7: its verdict on the fit)
    doc = json.loads((out / "fit.json").read_text())
    chain = (out / "chain.h5").read_bytes()
    os.remove(out / "fit.json")
    os.remove(out / "posterior.nc")
    with open(out / "corner.png", "r+b") as f:
        f.truncate(100)
    code, err = run_command(argv)
    assert code == status, err
    assert _without_timing(json.loads((out / "fit.json").read_text())) == _without_timing(doc)
    assert (out / "chain.h5").read_bytes() == chain and (out / "corner.png").stat().st_size > 100
    code, err = run_command(argv)  # complete now: refused as before
    assert code == 2 and "already holds" in err and "--force" in err


@pytest.mark.slow  # three processes of `brdfscale fit`: ~1–3 minutes on 2 cores
def test_fit_command_sigkilled_during_its_report_resumes(tmp_path):
    """A real SIGKILL of ``brdfscale fit`` once its report has begun (its first figure is in
    place, fit.json not yet): the rerun resumes the report and gives the uninterrupted run's."""
    measurements = _measurements(tmp_path)
    command = [sys.executable, "-m", "brdfscale", "--no-compilation-cache"]
    env = {**os.environ, "MPLBACKEND": "Agg", "BRDFSCALE_PROGRESS": "0"}
    reference = tmp_path / "reference"
    first = subprocess.run(command + _fit_argv(measurements, reference), env=env, capture_output=True, text=True)
    assert first.returncode in (0, 5, 6, 7), first.stderr
    out = tmp_path / "out"
    proc = subprocess.Popen(command + _fit_argv(measurements, out), env=env, stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 600
    while not (out / "data_vs_fit.png").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "fit.json").exists()
    rerun = subprocess.run(command + _fit_argv(measurements, out), env=env, capture_output=True, text=True)
    assert rerun.returncode == first.returncode, rerun.stderr
    assert "resuming the report" in rerun.stdout
    assert comparable_report(reference) == comparable_report(out)
    with h5py.File(reference / "chain.h5") as f, h5py.File(out / "chain.h5") as g:
        assert np.array_equal(f["chain"][()], g["chain"][()])


@pytest.mark.slow  # the fuzz family's quick run in its own process (imports, two samplers' compilation)
def test_fuzz_checkpoints_quick_has_no_bad_outcome(tmp_path):
    run = subprocess.run(
        [sys.executable, "-m", "experiments._fuzz_checkpoints", "--quick", "--json", str(tmp_path / "r.json")],
        capture_output=True,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg", "BRDFSCALE_PROGRESS": "0"},
    )
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads((tmp_path / "r.json").read_text())
    for kind, row in result["kinds"].items():
        assert row["tried"] > 0 and row["bad"] == 0, (kind, row, result["bad_examples"])


_ON_A_FULL_DISK = """
import sys, jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import brdfscale
from brdfscale import fitting
from tests.helpers import Linear, linear_measurements
path, check = sys.argv[1], sys.argv[2]
if check == "off":  # HDF5 driven into the full disk itself
    brdfscale.files.require_free_space = lambda *args, **kwargs: None
data = fitting.Dataset.from_measurements(linear_measurements())
problem, res = fitting.Problem(Linear(), data), fitting.fit(Linear(), data, starts=1)
kw = dict(sampler=fitting.Emcee(walkers=64), chains=4, steps=1200, chunk=100, progress=False)
try:
    fitting.sample(problem, res, checkpoint=path, **kw)
    print("completed")
except brdfscale.OutputWriteError as err:
    print("refused:", err)
"""


@pytest.mark.slow  # a real tmpfs (root on Linux only) and three processes
@pytest.mark.parametrize("check", ["on", "off"])
def test_a_real_full_tmpfs(tmp_path, check):
    """A 4 MiB tmpfs holds a few hundred of the 1200 steps: the run stops with the library's one-line
    error (before the chunk, from the free-space check; or, with that check off, from HDF5's own
    ENOSPC at the write) — no HDF5 dump, no crash — and the committed chunks, copied to a disk
    with room, resume to the chain of an uninterrupted run bit for bit."""
    if sys.platform != "linux" or os.geteuid() != 0:
        pytest.skip("a real full disk needs root on Linux (mount -t tmpfs); the injected ENOSPC tests cover the rest")
    where = tmp_path / "tmpfs"
    where.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(where)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"mount -t tmpfs failed here: {mounted.stderr.decode().strip()}")
    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    try:
        run = subprocess.run(
            [sys.executable, "-c", _ON_A_FULL_DISK, str(where / "c.h5"), check], capture_output=True, text=True, env=env
        )
        assert run.returncode == 0 and run.stdout.startswith("refused:") and "disk full" in run.stdout, run
        assert "HDF5" not in run.stderr and "Traceback" not in run.stderr and "Exception ignored" not in run.stderr
        shutil.copyfile(where / "c.h5", tmp_path / "c.h5")
    finally:
        subprocess.run(["umount", str(where)], capture_output=True)
    with h5py.File(tmp_path / "c.h5", "r") as f:
        assert int(f.attrs["steps_done"]) > 0
    resumed = subprocess.run(
        [
            sys.executable,
            "-c",
            _ON_A_FULL_DISK + "np.save(sys.argv[1] + '.npy', fitting.sample(problem, res, **kw).chain)\n"
            "np.save(sys.argv[1] + '.resumed.npy', fitting.sample(problem, res, checkpoint=path, **kw).chain)",
            str(tmp_path / "c.h5"),
            "on",
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    assert resumed.returncode == 0 and resumed.stdout.startswith("completed"), resumed
    assert np.array_equal(np.load(tmp_path / "c.h5.npy"), np.load(tmp_path / "c.h5.resumed.npy"))
