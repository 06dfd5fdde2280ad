"""Whether a report is written afresh, refused, or resumed: the one decision of ``brdfscale fit``'s report phase.

A run of ``brdfscale fit --out DIR`` fits, samples into ``DIR/chain.h5`` (a checkpoint, resumed
by :func:`fitting.sample` after a kill) and then writes the report (:func:`fitting.write_report`:
the figures, tables and ``posterior.nc`` first, ``fit.json`` last, each file atomically). A run
killed — or stopped by a full disk — while writing the report leaves some of those files and
no ``fit.json``. :func:`resume_report` tells that state from a finished report:

* no report file in ``DIR``, or ``overwrite``: a fresh report (``DIR`` checked and created by
  :func:`fitting.check_report_directory`);
* the report complete (:func:`report_problem`: ``fit.json`` a JSON object with every section of
  a report, and every file it lists present): refused, as :func:`fitting.check_report_directory`
  refuses it (an ``overwrite`` is needed);
* some report files but no complete report (``fit.json`` missing, cut short, or a file it lists
  gone), and — when the run samples — a checkpoint
  that verifies whole (:func:`fitting._checkpoint.verify`: every chunk's SHA-256, no NaN) and
  holds every step the run asks for: the report phase is resumed. The chain is not sampled
  again (``fitting.sample`` finds it complete and only reads it; the same fit, the same chain,
  so the same report), and the report's files are written anew over the partial ones;
* some report files and no complete chain where the run samples: refused (those files are not
  this run's report in progress).

Verified in tests/test_checkpoint_integrity.py (report files deleted or truncated after a
complete run, and a real SIGKILL of the command during its report).
"""

import json
import os

from brdfscale import InvalidInputError
from brdfscale.checks import flag
from brdfscale.choices import SAMPLE

from ._checkpoint import verify
from ._report import check_report_directory, report_files


__all__ = ["REPORT_KEYS", "report_problem", "resume_report"]


#: What every complete report's fit.json holds (:func:`fitting.write_report` writes it last, when
#: every file it lists is in place).
REPORT_KEYS = ("model", "data", "parameters", "ratios", "identifiability", "optimisation", "mcmc", "figures", "tables")


def report_problem(directory) -> str | None:
    """Why the report of :func:`fitting.write_report` in ``directory`` is not complete, or None
    when it is: its ``fit.json`` (written last) present, a JSON object with every section of a
    report (:data:`REPORT_KEYS`), and every file it lists (figures, tables, posterior) present
    beside it. The one check of a finished report, for ``brdfscale fit`` (:func:`resume_report`)
    and for each material of a library (``brdfscale.library``). Verified in
    tests/test_checkpoint_integrity.py and tests/test_library_robustness.py."""
    return _report_state(directory)[0]


def _report_state(directory) -> tuple[str | None, dict | None]:
    """:func:`report_problem`'s answer and the report's ``mcmc.stopped`` record (:func:`_stopped`; None where there
    is none), from one read of ``fit.json``."""
    directory = os.fspath(directory)
    try:
        with open(os.path.join(directory, "fit.json"), encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        return "no fit.json (the report is incomplete)", None
    except (OSError, ValueError, RecursionError) as err:
        return f"fit.json is unreadable ({' '.join(str(err).split())[:160]})", None
    if not isinstance(doc, dict):
        return "fit.json is not a report", None
    stopped = _stopped(doc)
    missing = [key for key in REPORT_KEYS if key not in doc]
    if missing:
        return f"fit.json is incomplete (no {', '.join(missing)})", stopped
    if not isinstance(doc["figures"], list) or not isinstance(doc["tables"], (list, str)):
        return "fit.json's list of figures or tables is damaged", stopped
    listed = [*doc["figures"], *(doc["tables"] if isinstance(doc["tables"], list) else [])]
    if isinstance(doc.get("posterior"), str) and not doc["posterior"].startswith("not written"):
        listed.append(doc["posterior"])
    for file in listed:
        if not isinstance(file, str):
            return "fit.json lists a file that is not a path", stopped
        if not os.path.isfile(os.path.join(directory, os.path.basename(file))):
            return f"{os.path.basename(file)}, listed in fit.json, is missing", stopped
    if stopped is not None:
        return (
            f"its sampling stopped at the time limit after {stopped.get('steps')} of {stopped.get('steps_asked')} "
            "steps",
            stopped,
        )
    return None, None


def _stopped(doc: dict) -> dict | None:
    """A report's record of a sampling run ended at its time limit (``mcmc.stopped``: :attr:`SampleResult.stopped`),
    or None."""
    mcmc = doc.get("mcmc")
    stopped = mcmc.get("stopped") if isinstance(mcmc, dict) else None
    return stopped if isinstance(stopped, dict) else None


def resume_report(out_dir, overwrite: bool = False, *, checkpoint=None, steps: int | None = 0) -> str | None:
    """Decide, before the long work, whether a report into ``out_dir`` is fresh or resumed (module docstring).

    Args:
        out_dir: the report's directory.
        overwrite: replace whatever is there (no resume: a fresh report; the checkpoint is the
            sampler's to restart).
        checkpoint: the run's checkpoint path (``DIR/chain.h5`` for ``brdfscale fit``); needed
            when ``steps`` > 0.
        steps: the draws per chain the run asks for (after a NUTS/HMC warm-up; all steps for
            emcee and IMH); 0 when it does not sample; None: the default steps of the sampler the checkpoint
            records (:meth:`brdfscale.choices.SampleDefaults.steps_for`: the one :class:`fitting.Auto` chose).

    A report whose sampling ended at its time limit (fit.json's ``mcmc.stopped``) is a report in progress: its chain
    continues (the run samples from the checkpoint up to the steps asked) and its files are written anew.

    Returns:
        None for a fresh report, or one line saying that the report phase is resumed and why.

    Raises:
        InvalidInputError: ``out_dir`` holds a complete report (or report files beside no
            complete chain) and ``overwrite`` is False — the message lists the files; the
            checkpoint belongs to an earlier layout.
        MeasurementFileError: ``out_dir`` is not a directory or cannot be created; the checkpoint
            is damaged (the message names the chunk and what to do).
    """
    overwrite = flag(overwrite, "overwrite")
    if overwrite:
        check_report_directory(out_dir, True)
        return None
    if not os.path.isdir(out_dir) or not any(os.path.lexists(p) for p in report_files(out_dir)):
        check_report_directory(out_dir, False)  # nothing there: creates the directory (or names what is wrong)
        return None
    problem, stopped = _report_state(out_dir)
    if problem is None:
        return _refuse(out_dir, "")  # a finished report: refused, its files listed
    if steps == 0:
        return (
            f"resuming the report in {out_dir}: {problem} and the run samples nothing; "
            "the fit is made again and the report's files are written anew"
        )
    if checkpoint is None or not os.path.isfile(checkpoint):
        return _refuse(out_dir, " There is no chain beside them, so they are not a report in progress of this run.")
    stored, record = verify(checkpoint)
    if stopped is not None:  # a report of a run ended at its time limit: its chain continues
        return (
            f"resuming the report in {out_dir}: {problem}; the chain {checkpoint} ({stored.steps} steps, every chunk "
            "verified) continues and the report's files are written anew"
        )
    sampler = record["signature"].get("sampler", {})
    warmup = int(sampler.get("warmup", 0))  # NUTS/HMC keep it in the chain
    if steps is None:
        steps = SAMPLE.steps_for(sampler.get("name", ""))
    if stored.steps < warmup + steps:
        return _refuse(
            out_dir,
            f" Its chain {checkpoint} holds {stored.steps} of the {warmup + steps} steps asked, so they are not a "
            "report in progress of this run.",
        )
    return (
        f"resuming the report in {out_dir}: {problem}; the chain {checkpoint} is complete "
        f"({stored.steps} steps, every chunk verified) and is not sampled again; the report's files are written anew"
    )


def _refuse(out_dir, why: str) -> None:
    """:func:`fitting.check_report_directory`'s refusal of the report files in ``out_dir``, ``why``
    added; None (a fresh report) where they have gone meanwhile."""
    try:
        check_report_directory(out_dir, False)
    except InvalidInputError as err:
        raise InvalidInputError(f"{err}{why}") from None
    return None
