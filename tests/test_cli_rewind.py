"""``brdfscale fit … --rewind-checkpoint``: the command line's way to keep the verified chunks of a
damaged ``DIR/chain.h5`` (:func:`fitting.rewind_checkpoint`) and continue from the last good
one — the remedy a refused damaged checkpoint names, in the command's words (``--rewind-checkpoint``,
never the Python call). End to end (slow): the rewound run's chain and report are the
undamaged run's, bit for bit where the chain is concerned."""

import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from brdfscale import fitting, MeasurementFileError
from brdfscale._cli import in_flags
from tests.helpers import comparable_report, Linear, linear_measurements, run_cli, sampled_fit_argv, write_sampled_set
from tests.references.damage import chunk_extents, flip_bit


def _edit_chunk(path, dataset: str, k: int) -> None:
    """Flip one bit in the middle of HDF5 chunk ``k`` of ``dataset``."""
    offset, size = chunk_extents(path)[dataset][k]
    flip_bit(path, offset + size // 2)


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("brdfscale fit: error: "), err
    return lines[0]


def test_the_refusal_of_a_damaged_checkpoint_names_the_flag(tmp_path):
    """A real refusal of :func:`fitting.sample` (chunk 1 damaged, chunk 0 verifies) offers the
    rewind; in the command's words that is ``--rewind-checkpoint``, and the Python call is gone."""
    import jax

    jax.config.update("jax_enable_x64", True)
    data = fitting.Dataset.from_measurements(linear_measurements())
    problem = fitting.Problem(Linear(), data)
    result = fitting.fit(Linear(), data, starts=1)
    kw = dict(sampler=fitting.Emcee(walkers=8), steps=20, chunk=10, seed=1, progress=False)
    path = tmp_path / "chain.h5"
    fitting.sample(problem, result, checkpoint=path, **kw)
    _edit_chunk(path, "chain", 1)
    with pytest.raises(MeasurementFileError) as caught:
        fitting.sample(problem, result, checkpoint=path, **kw)
    message = str(caught.value)
    assert "fitting.rewind_checkpoint(path)" in message and str(path) in message
    line = in_flags(message)
    assert "with --rewind-checkpoint and run again, or pass --force to start afresh" in line, line
    assert "rewind_checkpoint" not in line


def _measurements(tmp_path) -> str:
    return write_sampled_set(tmp_path / "m.exr")


def _argv(measurements, out, *extra) -> list[str]:
    # 400 steps: two chunks of fitting's default 200 (choices.SAMPLE.chunk)
    return [*sampled_fit_argv(measurements, out, steps=400, chains=1), *extra]


@pytest.mark.parametrize(
    "extra, damaged, expected",
    [
        (["--force"], True, "--rewind-checkpoint keeps the verified steps of DIR/chain.h5 and --force starts it"),
        ([], False, "--rewind-checkpoint: there is no checkpoint"),
    ],
    ids=["with --force", "no checkpoint"],
)
def test_what_cannot_be_rewound_is_refused_in_one_line(tmp_path, extra, damaged, expected):
    out = tmp_path / "out"
    out.mkdir()
    if damaged:
        (out / "chain.h5").write_bytes(b"not a checkpoint")
    code, _, err = run_cli(_argv(_measurements(tmp_path), out, "--rewind-checkpoint", *extra))
    assert code == 2 and expected in _one_error_line(err)
    assert not damaged or (out / "chain.h5").read_bytes() == b"not a checkpoint"  # left as it was


@pytest.mark.slow  # three runs of `brdfscale fit` with 400 emcee steps: ~30–90 s on 2 cores
def test_a_rewound_run_gives_the_undamaged_run_s_chain_and_report(tmp_path):
    """The uninterrupted run; then its checkpoint, alone in a new directory (a run killed while
    sampling) with its second chunk damaged: refused in one line naming ``--rewind-checkpoint``,
    the file left as it was; with the flag, the first chunk is kept, the second sampled again,
    and the chain and report equal the uninterrupted run's. While another process holds the
    checkpoint's lock the rewind is refused (exit 3) and the file left as it was."""
    measurements = _measurements(tmp_path)
    reference = tmp_path / "reference"
    status, _, err = run_cli(_argv(measurements, reference))
    assert status in (0, 5, 6, 7), err  # the report is complete (5–7: its verdict on the fit)
    out = tmp_path / "out"
    out.mkdir()
    shutil.copyfile(reference / "chain.h5", out / "chain.h5")
    _edit_chunk(out / "chain.h5", "chain", 1)
    damaged = (out / "chain.h5").read_bytes()
    code, _, err = run_cli(_argv(measurements, out))
    line = _one_error_line(err)
    assert code == 2 and "chunk 1 (steps 200–399) fails its SHA-256 check" in line, line
    assert "--rewind-checkpoint" in line and "fitting." not in line
    assert (out / "chain.h5").read_bytes() == damaged and not (out / "fit.json").exists()

    holder = subprocess.Popen(  # another run holding the checkpoint: the rewind waits for nobody
        [
            sys.executable,
            "-c",
            "import sys; from brdfscale import files\n"
            f"with files.exclusive({str(out / 'chain.h5')!r}, what='checkpoint'):\n"
            "    print('held', flush=True); sys.stdin.read()",
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        code, _, err = run_cli(_argv(measurements, out, "--rewind-checkpoint"))
        assert code == 3 and "another run is writing this checkpoint" in _one_error_line(err)
        assert (out / "chain.h5").read_bytes() == damaged
    finally:
        holder.communicate("")

    code, text, err = run_cli(_argv(measurements, out, "--rewind-checkpoint"))
    assert code == status, err
    assert f"rewound {out / 'chain.h5'}: its first 200 steps verify and are kept" in text, text
    with h5py.File(reference / "chain.h5", "r") as a, h5py.File(out / "chain.h5", "r") as b:
        assert int(b.attrs["steps_done"]) == 400
        for name in ("chain", "log_prob"):
            assert np.array_equal(a[name][()], b[name][()]), name
    assert comparable_report(reference) == comparable_report(out)
