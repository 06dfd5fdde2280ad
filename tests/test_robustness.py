"""Nothing lost, nothing silently wrong (issue 16): file integrity, exclusive runs, a command
line without tracebacks, temporary files of killed writes — each reported defect as a
regression test, plus property-based fuzzing of files and command lines."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, HealthCheck, settings, strategies as st

import brdfscale as bs
from brdfscale import _files, exr, files
from brdfscale._cli import main
from brdfscale.exr import _format
from tests.helpers import HOSTILE, rewrite_exr, run_command, same_set, sample_set, SYNTH_DOMAINS


P = _format.PREFIX


@pytest.fixture(scope="module")
def original(tmp_path_factory):
    path = tmp_path_factory.mktemp("robust") / "m.exr"
    exr.write_measurements(path, sample_set())
    return str(path), Path(path).read_bytes(), exr.read_measurements(path)


def _rewritten(original, tmp_path, edit, reseal=False):
    out = str(tmp_path / "edited.exr")
    rewrite_exr(original[0], out, edit, reseal=reseal)
    return out


# -- 1. integrity -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "edit",
    [
        lambda i, h, c: h.__setitem__(P + "mu", h[P + "mu"] * 2) if i == 0 else None,  # μ = 2 → 4
        lambda i, h, c: h.__setitem__(P + "extent", h[P + "extent"] * 1.5) if i == 1 else None,
        lambda i, h, c: h.__setitem__(P + "incident", np.array([0.0, 0.6, 0.8])) if i == 0 else None,
        lambda i, h, c: h.__setitem__(P + "metadata", json.dumps({"surface": {"name": "other"}})) if i == 0 else None,
    ],
    ids=["mu", "extent", "incident", "metadata"],
)
def test_a_changed_header_attribute_is_refused(original, tmp_path, edit):
    with pytest.raises(bs.MeasurementFileError, match=r"part \d .*'brdfscale.header_digest': does not match"):
        exr.read_measurements(_rewritten(original, tmp_path, edit))


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda i, h, c: c.pop("mask") if i == 1 else None, r"\['mask'\] listed in 'brdfscale.checksums' but missing"),
        (lambda i, h, c: [c.pop(k) for k in ("sigma.R", "sigma.G", "sigma.B")] if i == 0 else None, "but missing"),
        (
            lambda i, h, c: (
                h.__setitem__(
                    P + "checksums",
                    json.dumps({k: v for k, v in json.loads(h[P + "checksums"]).items() if k != "mask"}),
                )
                if i == 0
                else None
            ),
            r"no checksum for channel 'mask'",
        ),
        (lambda i, h, c: c.__setitem__("Z", c["R"].copy()) if i == 0 else None, r"unexpected channel\(s\) \['Z'\]"),
    ],
    ids=["mask removed", "sigma removed", "mask unlisted", "channel added"],
)
def test_channels_must_match_their_checksums(original, tmp_path, edit, match):
    # re-sealed: even a writer that recomputes the digest cannot drop or add a channel
    with pytest.raises(bs.MeasurementFileError, match=match):
        exr.read_measurements(_rewritten(original, tmp_path, edit, reseal=True))


def _as_version_1(i, h, c):
    h.pop(P + _format.DIGEST, None)
    h[P + "version"] = 1


def test_files_of_layout_1_stay_readable_with_a_warning(original, tmp_path):
    path = _rewritten(original, tmp_path, _as_version_1)
    with pytest.warns(bs.UnprotectedHeaderWarning, match="not protected"):
        back = exr.read_measurements(path)
    assert same_set(back, original[2])
    rewritten = tmp_path / "again.exr"
    exr.write_measurements(rewritten, back)  # read and write again: protected
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert same_set(exr.read_measurements(rewritten), original[2])


def test_layout_1_with_a_digest_is_a_downgrade_and_refused(original, tmp_path):
    path = _rewritten(original, tmp_path, lambda i, h, c: h.__setitem__(P + "version", 1))
    with pytest.raises(bs.MeasurementFileError, match="layout 1 never had"):
        exr.read_measurements(path)


def test_non_utf8_attribute_is_the_librarys_error(original, tmp_path):
    # the example: one byte of `half_slope` replaced by 0xff
    data = bytearray(original[1])
    data[data.find(b"half_slope") + 3] = 0xFF
    path = tmp_path / "bad.exr"
    path.write_bytes(bytes(data))
    with pytest.raises(bs.MeasurementFileError):
        exr.read_measurements(path)


@pytest.mark.parametrize(
    "text, match",
    [
        ('{"a": ' + "[" * 5000 + "]" * 5000 + "}", "nested"),
        ('{"a": ' + "[" * 70 + "]" * 70 + "}", "nested 71 deep"),
        ('{"n": ' + "7" * 5000 + "}", "not valid JSON"),
        ('{"x": NaN}', "not valid JSON"),
    ],
)
def test_hostile_metadata_json_is_refused(original, tmp_path, text, match):
    edit = lambda i, h, c: h.__setitem__(P + "metadata", text) if i == 0 else None  # noqa: E731
    with pytest.raises(bs.MeasurementFileError, match=match):
        exr.read_measurements(_rewritten(original, tmp_path, edit, reseal=True))


def test_writers_refuse_metadata_the_reader_would_refuse(tmp_path):
    deep = {}
    node = deep
    for _ in range(_format.MAX_JSON_DEPTH + 1):
        node["x"] = {}
        node = node["x"]
    mset = bs.MeasurementSet(sample_set().images, {"deep": deep})
    with pytest.raises(bs.InvalidInputError, match="nested"):
        exr.write_measurements(tmp_path / "deep.exr", mset)


def test_a_header_declaring_huge_images_is_refused_before_decoding(original, tmp_path):
    data = bytearray(original[1])
    at = data.find(b"dataWindow")  # name\0 type\0 size(4) then xMin yMin xMax yMax (int32)
    value = at + len(b"dataWindow\0box2i\0") + 4
    data[value + 8 : value + 12] = (2**30).to_bytes(4, "little")
    path = tmp_path / "huge.exr"
    path.write_bytes(bytes(data))
    with pytest.raises(bs.MeasurementFileError):
        exr.read_measurements(path)


def test_info_names_what_a_path_is(tmp_path, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    link = tmp_path / "link.exr"
    link.symlink_to(tmp_path / "gone.exr")
    for path, match in ((os.devnull, "not a regular file"), (fifo, "not a regular file"), (link, "symbolic link to")):
        assert main(["--no-compilation-cache", "info", str(path)]) == 2
        assert match in capsys.readouterr().err


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_info_says_permission_denied(original, tmp_path, capsys):
    path = tmp_path / "private.exr"
    path.write_bytes(original[1])
    path.chmod(0)
    assert main(["--no-compilation-cache", "info", str(path)]) == 2
    assert "permission denied" in capsys.readouterr().err


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mutated_files_are_refused_or_read_identically(original, tmp_path, data):
    """Property: whatever bytes change, the reader gives the library's error or the same data."""
    path, raw, reference = original
    b = bytearray(raw)
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, len(b) - 1))
        b[i] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        b = b[: data.draw(st.integers(0, len(b)))]
    mutant = tmp_path / "mutant.exr"
    mutant.write_bytes(bytes(b))
    try:  # OpenEXR's diagnostics are captured by the reader (brdfscale/exr/_diagnostics.py)
        back = exr.read_measurements(mutant)
    except bs.MeasurementFileError:
        return
    assert same_set(back, reference)


# -- temporary files of killed writes ---------------------------------------------------------------


def test_a_stale_temporary_file_is_removed_by_the_next_write(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = _files._host()
    stale = tmp_path / f".m.exr.brdfscale-{host}-{dead.pid}-abc.tmp.exr"
    stale.write_bytes(b"half")
    live = tmp_path / f".m.exr.brdfscale-{host}-{os.getppid()}-xyz.tmp.exr"  # a live process's: kept
    live.write_bytes(b"busy")
    exr.write_measurements(tmp_path / "m.exr", sample_set())
    assert not stale.exists() and live.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["m.exr", live.name])


def test_sigkill_during_writes_leaves_nothing_after_the_next_write(tmp_path):
    script = textwrap.dedent(f"""
        import numpy as np
        from brdfscale import files
        big = np.random.default_rng(0).random(4_000_000).tobytes()
        print("ready", flush=True)
        while True:
            files.atomic_write({str(tmp_path / "out.bin")!r}, lambda t: open(t, 'wb').write(big * 4), overwrite=True)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    import time

    time.sleep(1.0)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    files.atomic_write(tmp_path / "out.bin", lambda t: open(t, "wb").write(b"ok"), overwrite=True)
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"]
    assert (tmp_path / "out.bin").read_bytes() == b"ok"


# -- 2. exclusive runs ---------------------------------------------------------------------------


def _holder(target):
    """A subprocess holding the lock on ``target`` until its stdin closes."""
    script = (
        f"import sys\nfrom brdfscale import files\nwith files.exclusive({str(target)!r}):\n"
        "    print('held', flush=True)\n    sys.stdin.read()\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_run_is_refused_naming_the_holder_and_a_killed_ones_lock_is_taken_over(tmp_path):
    proc = _holder(tmp_path)
    try:
        with pytest.raises(bs.OutputInUseError, match=f"process {proc.pid} on .* started 20"):
            with files.exclusive(tmp_path):
                pass
    finally:
        proc.kill()  # SIGKILL: no cleanup runs; its record stays behind
        proc.wait()
    with files.exclusive(tmp_path):  # the OS released the lock with the process
        record = json.loads((tmp_path / ".brdfscale.lock.holder.json").read_text())
        assert record["pid"] == os.getpid()
        with files.exclusive(tmp_path):  # re-entrant within a process
            pass


def test_sample_refuses_a_checkpoint_in_use(tmp_path):
    from brdfscale import fitting

    problem, result = _tiny_fit()
    checkpoint = tmp_path / "chain.h5"
    proc = _holder(checkpoint)
    try:
        with pytest.raises(bs.OutputInUseError, match="checkpoint"):
            fitting.sample(problem, result, sampler="emcee", steps=4, walkers=8, checkpoint=checkpoint, progress=False)
        assert not checkpoint.exists()
    finally:
        proc.kill()
        proc.wait()


def _tiny_fit():
    from brdfscale import fitting

    model = fitting.ParametricModel(fixed={"mu_c": 1.0, "exponent": 1.0, "alpha_max": 0.05})
    mset = fitting.simulate(
        model, {"amplitude": 1.0, "alpha_lobe": 0.02}, (1.0, 4.0), size=9, extent=0.1, noise=0.01, seed=0
    )
    data = fitting.Dataset.from_measurements(mset)
    result = fitting.fit(model, data, starts=1, seed=0)
    return fitting.Problem(model, data), result


def test_fit_command_refuses_an_output_directory_in_use(original, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    proc = _holder(out)
    try:
        status = main(
            ["--no-compilation-cache", "fit", original[0], "--out", str(out), "--steps", "0", "--starts", "1"]
        )
    finally:
        proc.kill()
        proc.wait()
    assert status == 3
    err = capsys.readouterr().err
    assert f"process {proc.pid}" in err and "Traceback" not in err
    assert not (out / "fit.json").exists()


# -- 3. the command line ---------------------------------------------------------------------------


def _bad_lines(measurements, tmp):
    existing = tmp / "existing"
    existing.touch()
    fit = ["fit", measurements, "--out", str(tmp / "d")]
    return [
        (fit + ["--walker", "8"], "unrecognized arguments: --walker"),
        (fit + ["--fix", "mu_c=1", "--fix", "mu_c=2"], "--fix mu_c given more than once"),
        (fit + ["--steps", "-1"], "argument --steps: must be an integer in [0, 1000000]"),
        (fit + ["--seed", "1180591620717411303424"], "argument --seed: must be an integer in"),
        (fit + ["--base-nodes", "100000"], "argument --base-nodes"),
        (fit + ["--knots", "100000"], "argument --knots"),
        (fit + ["--starts", "1000000000"], "argument --starts"),
        (fit + ["--walkers", "100000000"], "argument --walkers"),
        (fit + ["--default-sigma", "nan"], "argument --default-sigma: must be a finite number"),
        (
            fit + ["--model", "parametric", "--fix", "alpha_lobe=1e-30", "--steps", "0"],
            "--fix: fixed alpha_lobe = 1e-30 lies outside its prior box",
        ),
        (fit + ["--force", "--force"], "--force: given more than once"),
        (fit + ["--regularisation", "auto"], "--regularisation applies to the non-parametric model only"),
        (fit + ["--model", "nonparametric", "--regularisation", "-1"], "argument --regularisation"),
        (
            fit + ["--model", "parametric", "--sampler", "emcee", "--walkers", "4", "--steps", "10"],
            "--walkers 4: the model has 5 parameters",
        ),
        (fit + ["--sampler", "emcee", "--walkers", "4096", "--steps", "1000000"], "GiB"),
        (fit + ["--walkers", "16"], "--walkers applies to --sampler emcee only"),
        (fit + ["--sampler", "gibbs"], "argument --sampler"),
        (fit + ["--chains", "0"], "argument --chains"),
        (["demo", "--out", ""], "--out: give a directory name"),
        (["demo", "--out", str(existing)], "exists and is not a directory"),
        (["example", "--out", ""], "--out: give a directory name"),
        (["example", "--out", str(existing / "sub")], "is a file, not a directory"),
        (["synth", "gaussian", "--out", str(tmp / "x.exr"), "--extent", "1e300"], "argument --extent"),
        (["synth", "gaussian", "--out", str(tmp / "x.exr"), "--noise", "gaussian:1e300"], "argument --noise"),
        (["synth", "gaussian", "--out", str(tmp / "x.exr"), "--seed", "-3"], "argument --seed"),
        (["synth", "gaussian", "--out", str(tmp)], "is a directory"),
        (["synth", "gaussian", "--out", str(existing)], "file exists; pass --force"),
        (["synth", "gaussian", "--out", "", "--size", "16"], "--out: give a file name"),
        (["synth", "gaussian", "--out", str(tmp / "x.exr"), "--scales", "64", "--size", "32"], "exceeds the field's"),
    ]


def test_bad_command_lines_get_one_message_and_status_2(original, tmp_path, capsys):
    for argv, match in _bad_lines(original[0], tmp_path):
        try:
            status = main(["--no-compilation-cache", *argv])
        except SystemExit as exit_:  # argparse's usage errors
            status = exit_.code
        err = capsys.readouterr().err
        assert status == 2, (argv, err)
        assert match in err, (argv, err)
        assert "Traceback" not in err
        assert not (tmp_path / "d" / "fit.json").exists()


def test_a_wrong_flag_shows_the_subcommands_usage(original, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["fit", original[0], "--out", str(tmp_path), "--walker", "8"])
    assert capsys.readouterr().err.startswith("usage: brdfscale fit ")


def test_damaged_truth_metadata_is_refused_before_the_fit(tmp_path, capsys):
    mset = sample_set()
    bad = bs.MeasurementSet(mset.images, {"truth": {"params": {"alpha_lobe": "x"}}})
    path = tmp_path / "m.exr"
    exr.write_measurements(path, bad)
    argv = ["--no-compilation-cache", "fit", str(path), "--out", str(tmp_path / "o"), "--model", "parametric"]
    assert main([*argv, "--steps", "0"]) == 2  # the parametric model's truth (alpha_lobe) is checked
    err = capsys.readouterr().err
    assert "metadata truth.params.alpha_lobe must be a positive finite number" in err
    assert "fitting" not in capsys.readouterr().out


def test_an_unexpected_failure_is_one_line_and_status_1(monkeypatch, original, capsys):
    from brdfscale._cli import _info

    def broken(args):
        raise RuntimeError("something\nbroke")

    monkeypatch.setattr(_info, "run", broken)
    assert main(["--no-compilation-cache", "info", original[0]]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unexpected failure (RuntimeError: something broke)" in err
    assert "--debug" in err and "Traceback" not in err
    with pytest.raises(RuntimeError):
        main(["--no-compilation-cache", "--debug", "info", original[0]])


@settings(max_examples=40, deadline=None)
@given(
    option=st.sampled_from(sorted(SYNTH_DOMAINS)),
    value=st.one_of(
        st.sampled_from(HOSTILE),
        st.text(max_size=8),
        st.integers(-(10**25), 10**25).map(str),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
    ),
)
def test_synth_option_values_outside_their_domain_are_refused(option, value):
    """Property: a value outside an option's documented domain exits 2, before any work;
    (values inside it are the default test of test_cli_synth.py)."""
    if SYNTH_DOMAINS[option](value):
        return
    argv = ["synth", "gaussian", "--size", "16", "--pixels", "5", "--scales", "2,4", "--out", "/nonexistent/x.exr"]
    if option in argv:
        i = argv.index(option)
        del argv[i : i + 2]
    code, err = run_command(argv + [option, value])
    assert code == 2 and "Traceback" not in err, (option, value, err)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_demo_runs_again_into_its_own_directory_and_never_replaces_a_users_files(tmp_path, capsys):
    out = tmp_path / "demo"
    argv = ["--no-compilation-cache", "demo", "--out", str(out), "--source", "model", "--steps", "0", "--no-progress"]
    assert main(argv) == 0
    first = (out / "fit.json").read_text()
    assert main(argv) == 0  # README's main command, run again
    assert "replacing them" in capsys.readouterr().out
    assert json.loads((out / "fit.json").read_text())["parameters"] == json.loads(first)["parameters"]
    user = tmp_path / "user"
    user.mkdir()
    (user / "fit.json").write_text("mine")
    assert main([*argv[:3], str(user), *argv[4:]]) == 2
    assert "already holds fit.json" in capsys.readouterr().err
    assert sorted(p.name for p in user.iterdir() if not p.name.startswith(".brdfscale.lock")) == ["fit.json"]
    assert (user / "fit.json").read_text() == "mine"
