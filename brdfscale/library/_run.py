"""The library driver: batches of materials to tasks, in-process or on Ray; the index; resume."""

import dataclasses
import datetime
import json
import os
import re
import time
from typing import Any

from .._choices import EXECUTORS
from .._cluster import check_options, ray_session, resolve_executor
from .._compilation_cache import directory_in_use
from .._errors import InvalidInputError, MeasurementFileError, OutputWriteError
from .._files import exclusive, write_text
from .._json import json_text
from .._show import progress_bar, Shown, Table
from ._spec import FitSpec
from ._task import clear_partial, fit_batch, material_directory, report_problem, take_over


__all__ = ["fit_library", "LibraryResult", "find_materials", "INDEX"]

INDEX = "library.json"
_FORMAT = 1


def find_materials(sources) -> list:
    """``(name, path)`` of every measurement set among ``sources`` — files, and directories
    searched recursively for ``*.exr`` — in a stable order, each named after its path (the
    part below a given directory, ``/`` → ``__``, without ``.exr``), names unique. Hidden
    entries of a directory (names starting with ``.``) are left out: :func:`fit_library`
    lists them.

    Raises:
        InvalidInputError: a source that does not exist, one measurement file named twice (the
            same file after resolving links, e.g. a directory and a file inside it), or no
            measurement file at all.
    """
    return _find(sources)[0]


def _find(sources) -> tuple[list, list]:
    """:func:`find_materials`, and the hidden entries it left out (paths; directories end in ``/``)."""
    if isinstance(sources, (str, os.PathLike)):
        sources = [sources]
    found, hidden = [], []
    for source in sources:
        source = os.fspath(source)
        if os.path.isdir(source):
            for root, dirs, files in os.walk(source):
                hidden.extend(os.path.join(root, d) + os.sep for d in sorted(dirs) if d.startswith("."))
                dirs[:] = sorted(d for d in dirs if not d.startswith("."))
                for f in sorted(files):
                    if f.lower().endswith(".exr"):
                        path = os.path.join(root, f)
                        if f.startswith("."):
                            hidden.append(path)
                        else:
                            found.append((os.path.relpath(path, source), path))
        elif os.path.isfile(source):
            found.append((os.path.basename(source), source))
        else:
            raise InvalidInputError(
                f"{source}: no such file or directory (give measurement files or directories holding them)."
            )
    if not found:
        raise InvalidInputError(f"no measurement files (*.exr) in {', '.join(os.fspath(s) for s in sources)}.")
    named, seen, files = [], {}, {}
    for rel, path in found:
        real = os.path.realpath(path)
        if real in files:
            raise InvalidInputError(
                f"{path}: this measurement file is named twice (also as {files[real]}); give each file once "
                "(a directory counts every file below it)."
            )
        files[real] = path
        name = re.sub(r"[^A-Za-z0-9._-]+", "_", re.sub(r"\.exr$", "", rel, flags=re.I).replace(os.sep, "__"))
        name = name.lstrip(".") or "material"
        base, k = name, 1
        while name in seen:
            k += 1
            name = f"{base}-{k}"
        seen[name] = path
        named.append((name, os.path.abspath(path)))
    return named, hidden


@dataclasses.dataclass(repr=False)
class LibraryResult(Shown):
    """What a library run did: the index's materials (name → record), this run's counts and time."""

    out: str
    materials: dict
    done: int
    failed: int
    skipped: int
    seconds: float
    executor: str

    @property
    def failures(self) -> dict:
        return {n: r["error"] for n, r in self.materials.items() if r["status"] == "failed"}

    def _show_items(self):
        total = len(self.materials)
        return [
            ("out", self.out),
            ("materials", total),
            ("done", sum(r["status"] == "done" for r in self.materials.values())),
            ("failed", self.failed),
            ("this run", f"{self.done} fitted, {self.skipped} already done, {self.seconds:.1f} s on {self.executor}"),
        ]

    def _show_tables(self):
        return [
            Table(
                "materials",
                ("material", "status", "χ²/dof", "fit", "error"),
                [
                    (n, r["status"], r.get("reduced_chi2"), r.get("fit_status"), r.get("error"))
                    for n, r in self.materials.items()
                ],
            )
        ]

    def table(self) -> str:
        """The summary table the command prints."""
        rows = [
            ("materials", len(self.materials)),
            ("done (all runs)", sum(r["status"] == "done" for r in self.materials.values())),
            ("fitted this run", self.done),
            ("already done", self.skipped),
            ("failed", self.failed),
            ("time", f"{self.seconds:.1f} s"),
            ("materials/s", f"{self.done / self.seconds:.2f}" if self.seconds > 0 and self.done else "—"),
            ("executor", self.executor),
        ]
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


_STATUSES = ("done", "failed", "pending")


def _schema_problem(doc) -> str | None:
    """What makes ``doc`` (a parsed ``library.json``) not an index of this version, or None.

    The schema: an object with ``format`` 1, ``spec`` an object (the :class:`FitSpec`), ``runs`` a
    list of objects, and ``materials`` an object of name → object with ``source`` (a string),
    ``status`` (``done``, ``failed`` or ``pending``), ``attempts`` (an integer ≥ 0) and, when
    failed, ``error`` (a string)."""
    if not isinstance(doc, dict):
        return f"a JSON {type(doc).__name__} where an object is expected"
    if doc.get("format") != _FORMAT:
        return f"format {doc.get('format')!r} where {_FORMAT} is expected"
    for key, kind, what in (("spec", dict, "an object"), ("runs", list, "a list"), ("materials", dict, "an object")):
        if key not in doc:
            return f"no {key!r}"
        if not isinstance(doc[key], kind):
            return f"{key!r} is a JSON {type(doc[key]).__name__}, not {what}"
    for k, run in enumerate(doc["runs"]):
        if not isinstance(run, dict):
            return f"runs[{k}] is not an object"
    for name, entry in doc["materials"].items():
        where = f"materials[{name!r}]"
        if not isinstance(entry, dict):
            return f"{where} is not an object"
        if not isinstance(entry.get("source"), str):
            return f"{where} has no source path" if "source" not in entry else f"{where}'s source is not a string"
        if entry.get("status") not in _STATUSES:
            return f"{where}'s status is {entry.get('status')!r}, not one of {', '.join(_STATUSES)}"
        attempts = entry.get("attempts")
        if isinstance(attempts, bool) or not isinstance(attempts, int) or attempts < 0:
            return f"{where}'s attempts is {attempts!r}, not an integer ≥ 0"
        if entry["status"] == "failed" and not isinstance(entry.get("error"), str):
            return f"{where} failed without an error message"
    return None


def _unwritable(doc) -> str | None:
    """Why ``doc`` could not be written back (e.g. nested too deep for the encoder), or None."""
    try:
        json_text(doc)
    except (TypeError, ValueError, RecursionError) as err:
        return f"cannot be written back: {type(err).__name__}"
    return None


def spec_differences(recorded: dict, spec: FitSpec) -> str:
    """The options of an index's recorded spec that differ from ``spec``, as ``name=recorded value, …``
    ("" if none). A key the index lacks was recorded before the option existed: its default (FitSpec's
    fields). ``starts`` is compared as the count it means for the spec's model (:meth:`FitSpec.starts_count`):
    an index written before ``starts="auto"`` recorded the count (8), which ``"auto"`` still means for every
    model but the anisotropic non-parametric one (1)."""
    recorded = {**FitSpec().to_json(), **recorded}
    mine = spec.to_json()
    if recorded["model"] == mine["model"]:
        try:
            recorded["starts"], mine["starts"] = spec.starts_count(recorded["starts"]), spec.starts_count()
        except InvalidInputError:  # a recorded value that is no count: compared as it is
            pass
    return ", ".join(f"{k}={recorded.get(k)!r}" for k in sorted(mine) if recorded.get(k) != mine[k])


class _Index:
    """``OUT/library.json``: the options, and per material its source and last record. Written
    atomically by the driver alone (after every batch), its schema checked on every start
    (:func:`_schema_problem`); the material directories are the truth it is reconciled with: a
    directory whose report verifies (:func:`report_problem`) counts as done, also without an
    index entry (a driver killed after a task finished); one whose report does not is fitted
    again, resuming from what it holds."""

    def __init__(self, out: str, spec: FitSpec, materials: list, force: bool, say):
        self.path = os.path.join(out, INDEX)
        kept = None
        if os.path.lexists(self.path):
            try:
                with open(self.path, encoding="utf-8") as f:
                    doc = json.load(f)
            except (OSError, ValueError, RecursionError) as err:
                problem = f"unreadable: {' '.join(str(err).split())[:200] or type(err).__name__}"
            else:
                problem = _schema_problem(doc) or _unwritable(doc)
            if problem:  # a damaged file, not a bad argument
                raise MeasurementFileError(
                    f"{self.path}: unreadable library index ({problem}); move it away (the reports in "
                    f"{os.path.join(out, 'materials')} are verified and kept) or give another out= directory."
                )
            changed = spec_differences(doc["spec"], spec)
            if changed and not force:
                raise InvalidInputError(
                    f"{out} holds a library fitted with other options (there {changed}); rerun with the same options "
                    "to continue it, or give another out= directory "
                    "(force=True refits every material with the new ones)."
                )
            kept = doc
        if kept is None or force:
            kept = {"format": _FORMAT, "created": _now(), "spec": spec.to_json(), "runs": [], "materials": {}}
        self.doc: dict = kept
        complete, damaged = [], []
        for name, path in materials:
            entry = self.doc["materials"].setdefault(name, {"source": path, "status": "pending", "attempts": 0})
            if entry["source"] != path:
                raise InvalidInputError(
                    f"material {name!r} of {out} came from {entry['source']}, now from {path}; "
                    "one name, one source: rename the file or give another out= directory."
                )
            final = material_directory(out, name)
            if not os.path.lexists(final):
                if entry["status"] == "done":
                    say(f"  {final} is missing: fitting {name} again")
                    entry.update(status="pending", note="its directory was missing: fitted again")
                continue
            if os.path.islink(final) or not os.path.isdir(final):
                raise InvalidInputError(
                    f"{final} is not a directory: the library keeps material {name}'s report there; move it away "
                    "or give another out= directory."
                )
            problem = report_problem(final)
            if problem is None:
                if entry["status"] != "done":
                    entry.update(status="done", note="found complete on restart (the index had not recorded it)")
                complete.append(name)
            else:
                damaged.append((name, final, problem))
        # everything checked: now what a killed or beaten attempt left beside a complete report
        # goes, and the damaged reports make way
        for name in complete:
            clear_partial(out, name)
        for name, final, problem in damaged:
            say(f"  {final}: {problem}; fitting {name} again{take_over(out, name)}")
            note = f"its report was damaged ({problem}): fitted again"
            self.doc["materials"][name].update(status="pending", note=note)

    def start_run(self, executor: str, todo: int) -> int:
        self.doc["runs"].append({"started": _now(), "executor": executor, "materials": todo, "finished": None})
        self.write()
        return len(self.doc["runs"])

    def update(self, record: dict, run: int):
        entry = self.doc["materials"][record["name"]]
        if record["status"] == "skipped":
            if entry["status"] != "done":
                entry.update(status="done", note="completed by another attempt")
            return
        entry["attempts"] = entry.get("attempts", 0) + 1
        entry.update({k: v for k, v in record.items() if k != "name"}, run=run, finished=_now())
        if record["status"] == "done":
            entry.pop("error", None)

    def finish_run(self, run: int, done: int, failed: int, seconds: float):
        self.doc["runs"][run - 1].update(finished=_now(), done=done, failed=failed, seconds=round(seconds, 3))
        self.write()

    def write(self):
        """Replace the index whole (the checked write path: a full disk is
        :class:`~brdfscale.OutputWriteError` and leaves the previous index in place)."""
        write_text(self.path, json_text(self.doc, indent=1), overwrite=True)


def _ray(address, workers):
    """Ray for the run (:func:`brdfscale._cluster.ray_session`: the cluster at ``address``, or a local instance of
    ``workers`` CPUs stopped at the end, by the watchdog :mod:`brdfscale._watchdog` should this process die first)."""
    return ray_session(address, workers, instead="run the library in-process, without address= and workers=")


def _batches(todo, batch):
    return [todo[i : i + batch] for i in range(0, len(todo), batch)]


def fit_library(
    sources,
    out,
    *,
    spec: FitSpec | None = None,
    batch: int = 16,
    executor: str = EXECUTORS.default,
    address: str | None = None,
    workers: int | None = None,
    cpus_per_task: float = 1,
    retries: int = 2,
    force: bool = False,
    progress: bool = True,
    stream=None,
) -> LibraryResult:
    """Fit every material of a library into ``out``: one :func:`fitting.fit_many` per batch of
    ``batch`` materials, each batch a task of its own, in this process or on a Ray cluster.

    Args:
        sources: measurement files and directories (searched recursively for ``*.exr``;
            :func:`find_materials` names the materials).
        out: the output directory (created): ``library.json`` (the index) and
            ``materials/NAME/`` per material (``fit.json``, figures, tables; ``posterior.nc`` when
            sampled, and the checkpoint ``chain.h5`` of a sampler that runs per material: emcee, imh,
            auto). Held for the run (a second run into it raises
            :class:`~brdfscale.OutputInUseError`).
        spec: the model and fit options (:class:`FitSpec`), the same for every material.
        batch: materials per task (≥ 1, default 16).
        executor: ``"process"`` — batches one after another in this process (JAX must be in
            float64, as for :func:`fitting.fit`); ``"ray"`` — batches as Ray tasks (a local
            Ray instance with ``workers`` CPUs, or the cluster at ``address``), JAX imported
            inside each task, float64 set there; ``"auto"`` (default) — Ray when ``address``
            or ``workers`` is given, else in-process.
        workers: CPUs of the local Ray instance (default: the machine's); tasks run ``cpus_per_task``
            CPUs each.
        retries: Ray's retries of a task whose worker died (default 2).
        force: refit every material (a library in ``out`` with other options is otherwise refused).
        progress: a progress bar over the materials.
        stream: where the per-material failures are reported as they come (a callable taking a line).

    Resumable: a material counts as done when its directory (moved into place whole by
    :mod:`brdfscale.library._task`) holds a report that verifies (``fit.json`` complete, every
    file it lists present); a rerun after any interruption fits only the others, each exactly
    once, and fits again — saying so through ``stream`` — a material whose report was damaged
    since. A material that fails (unreadable file, no valid fit) is recorded with its error in
    the index and retried by the next run; the library goes on. Hidden entries of a directory
    (names starting with ``.``) are listed through ``stream``. A local Ray instance started
    here is stopped when this process ends, however it ends (a watchdog process,
    :mod:`brdfscale._watchdog`). docs/library.md states the guarantees.

    Raises:
        InvalidInputError: bad arguments, a source that does not exist or named twice, an index
            of another job, ``out/materials`` or a material's directory that is not a directory.
        MeasurementFileError: a damaged index (not JSON, cut short, or failing its schema,
            which is checked on every start); it is left as it was.
        OutputInUseError: another run holds ``out``.
        OutputWriteError: the index or a report could not be written (a full disk): the
            previous index stays in place.
        MissingDependencyError: the Ray executor without Ray installed.
    """
    from ..checks import integer

    spec = FitSpec() if spec is None else spec
    if not isinstance(spec, FitSpec):
        raise InvalidInputError(f"spec must be a brdfscale.library.FitSpec; got {type(spec).__name__}.")
    batch = integer(batch, "batch", 1)
    workers, cpus_per_task, retries = check_options(workers, cpus_per_task, retries)
    executor = resolve_executor(executor, address, workers)
    if executor == "process":
        from ..checks import require_float64

        require_float64("brdfscale.library.fit_library (in-process)")
    materials, hidden = _find(sources)
    say = stream or (lambda line: None)
    if hidden:
        shown = ", ".join(hidden[:10]) + (f" and {len(hidden) - 10} more" if len(hidden) > 10 else "")
        entries = "entry" if len(hidden) == 1 else "entries"
        say(f"  skipped {len(hidden)} hidden {entries} (names starting with '.'; rename to include): {shown}")
    out = os.path.abspath(os.fspath(out))
    for directory in (out, os.path.join(out, "materials")):
        if os.path.lexists(directory) and not os.path.isdir(directory):
            raise InvalidInputError(
                f"{directory} exists and is not a directory (the library's "
                f"{'output' if directory == out else 'material reports'} go there); move it away or give another "
                "out= directory."
            )
    os.makedirs(os.path.join(out, "materials"), exist_ok=True)
    with exclusive(out, what="library directory"):
        if force:
            _clear(out, materials)
        index = _Index(out, spec, materials, force, say)
        todo = [(n, p) for n, p in materials if index.doc["materials"][n]["status"] != "done"]
        skipped = len(materials) - len(todo)
        run = index.start_run(executor, len(todo))
        t0 = time.perf_counter()
        counts = {"done": 0, "failed": 0, "skipped": 0}
        cache = directory_in_use()  # the workers share it, with the same settings

        def absorb(records, bar):
            for record in records:
                index.update(record, run)
                counts[record["status"]] += 1
                if record["status"] == "failed":
                    say(f"  failed: {record['name']}: {record['error']}")
            index.write()
            bar.update(len(records))

        with progress_bar(
            enabled=progress, total=len(materials), initial=skipped, desc="library", unit="material"
        ) as bar:
            if executor == "process":
                for chunk in _batches(todo, batch):
                    absorb(fit_batch(chunk, out, spec, batch=batch, compilation_cache=cache, float64=False), bar)
            elif todo:
                with _ray(address, workers) as ray:
                    remote: Any = ray.remote  # Any: Ray's stubs type a task's .remote() without its keywords
                    task = remote(num_cpus=cpus_per_task, max_retries=retries, retry_exceptions=False)(fit_batch)
                    pending = {
                        task.remote(chunk, out, spec, batch=batch, compilation_cache=cache): chunk
                        for chunk in _batches(todo, batch)
                    }
                    while pending:
                        ready, _ = ray.wait(list(pending), num_returns=1)
                        chunk = pending.pop(ready[0])
                        try:
                            records = ray.get(ready[0])
                        except Exception as err:  # noqa: BLE001 — the task died past its retries
                            if isinstance(getattr(err, "cause", None), OutputWriteError):
                                raise err.cause from None  # type: ignore[attr-defined] — a full disk stops the run
                            text = f"{type(err).__name__}: {' '.join(str(err).split())[:300]}"
                            records = [
                                {"name": n, "status": "failed", "error": f"task failed: {text}"} for n, _ in chunk
                            ]
                        absorb(records, bar)
        seconds = time.perf_counter() - t0
        index.finish_run(run, counts["done"], counts["failed"], seconds)
        return LibraryResult(
            out=out,
            materials=index.doc["materials"],
            done=counts["done"],
            failed=counts["failed"],
            skipped=skipped + counts["skipped"],
            seconds=seconds,
            executor=executor,
        )


def _clear(out, materials):
    """force=True: the earlier results of these materials go (only the library's own files)."""
    import shutil

    for name, _ in materials:
        if os.path.isdir(material_directory(out, name)) and not os.path.islink(material_directory(out, name)):
            shutil.rmtree(material_directory(out, name))
