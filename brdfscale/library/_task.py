"""One batch of a library: read, fit together (:func:`fitting.fit_many`), sample (NUTS and HMC
together, :func:`fitting.sample_many`; emcee, IMH and auto per material, checkpointed), report — the unit of
work that runs in the driver's process or as a Ray task (JAX is imported inside it).

Every material's report is written into ``materials/.NAME.partial/`` (held with
:func:`brdfscale.files.exclusive`) and renamed to ``materials/NAME/`` when complete, so a
task killed at any point leaves at most a ``.partial`` directory, which the next attempt
takes over (a sampler's checkpoint there resumes its chain). The rename cannot replace a
finished directory, so a material is never reported twice even if two attempts race. A
material counts as done when its directory's report verifies (:func:`report_problem`); one
damaged afterwards (``fit.json`` deleted, truncated, a listed file gone) is taken over
(:func:`take_over`) and fitted again.
"""

import contextlib
import os
import shutil
import time
import traceback

from .. import _compilation_cache
from .._errors import BrdfscaleError, InvalidInputError, OutputInUseError, OutputWriteError
from .._files import exclusive, write_failed
from ._spec import FitSpec


__all__ = ["clear_partial", "fit_batch", "material_directory", "partial_directory", "report_problem", "take_over"]


def material_directory(out: str, name: str) -> str:
    return os.path.join(out, "materials", name)


def partial_directory(out: str, name: str) -> str:
    return os.path.join(out, "materials", f".{name}.partial")


def report_problem(directory: str) -> str | None:
    """Why the material report in ``directory`` is not complete, or None when it is:
    :func:`fitting.report_problem`, the one check of a finished report, for the driver and the
    tasks alike (imported here on first use: a driver that only schedules Ray tasks imports the
    fitting stack only when it meets a report to check)."""
    from .. import fitting

    return fitting.report_problem(directory)


def take_over(out: str, name: str) -> str:
    """Clear the way for material ``name`` to be fitted again when its directory holds a damaged
    report: the directory becomes the material's partial one (where a sampler's checkpoint
    resumes its chain) or, when an earlier attempt left a partial directory, goes. Returns how, in
    words for the run's message.

    Raises:
        InvalidInputError: the directory cannot be moved or removed (naming it and why).
    """
    final, partial = material_directory(out, name), partial_directory(out, name)
    try:
        if not os.path.lexists(partial):
            os.rename(final, partial)
            return " (resuming from what its directory holds)"
        shutil.rmtree(final)
        return f" (resuming from {partial})"
    except OSError as err:
        raise InvalidInputError(
            f"{final}: its damaged report cannot be cleared away ({err.strerror or err}); move it away by hand."
        ) from None


def clear_partial(out: str, name: str) -> None:
    """Remove material ``name``'s partial directory, left beside its complete report by an attempt
    that lost a race or was killed, unless a live attempt holds it."""
    partial = partial_directory(out, name)
    if os.path.isdir(partial) and not os.path.islink(partial):
        with contextlib.suppress(OutputInUseError), exclusive(partial, what="material directory"):
            shutil.rmtree(partial, ignore_errors=True)


def _record(name, status, started, **fields):
    return {
        "name": name,
        "status": status,
        "seconds": round(time.perf_counter() - started, 3),
        "pid": os.getpid(),
        "host": os.uname().nodename,
        **fields,
    }


def _failure(err) -> str:
    if isinstance(err, BrdfscaleError):
        return f"{type(err).__name__}: {' '.join(str(err).split())}"
    frame = traceback.extract_tb(err.__traceback__)[-1] if err.__traceback__ else None
    where = f" (at {os.path.basename(frame.filename)}:{frame.lineno})" if frame else ""
    return f"unexpected {type(err).__name__}: {' '.join(str(err).split())[:300]}{where}"


def fit_batch(
    materials: list,
    out: str,
    spec: FitSpec,
    *,
    batch: int = 64,
    compilation_cache: str | None = None,
    float64: bool = True,
) -> list:
    """Fit ``materials`` (a list of ``(name, path)``) into ``out/materials/`` with the options
    ``spec`` (a :class:`FitSpec`); return one record per material: ``status`` ``"done"``
    (with χ², status, seconds), ``"skipped"`` (already done: its report verifies, :func:`report_problem`) or
    ``"failed"`` (with ``error``: the file could not be read, or its fit could not be made).

    ``float64``: switch JAX to float64 (what a worker process does; the in-process runner
    leaves the caller's setting alone and requires float64 like :func:`fitting.fit`).
    ``compilation_cache``: JAX's persistent compilation cache directory for this process
    (the one the command uses, shared by every worker of a host), set up with every setting the
    command uses (:func:`brdfscale._compilation_cache.enable`).
    """
    import jax

    if float64:
        jax.config.update("jax_enable_x64", True)
    if compilation_cache:
        _compilation_cache.enable(compilation_cache)
    from .. import exr, fitting

    started = time.perf_counter()
    records, todo = [], []
    for name, path in materials:
        if os.path.isdir(material_directory(out, name)) and report_problem(material_directory(out, name)) is None:
            records.append(_record(name, "skipped", started))
            continue
        t0 = time.perf_counter()
        try:
            mset = exr.read_measurements(path)
            data = spec.dataset(mset)
            model, info = spec.model_for(data)
            truth = fitting.truth_of(model, mset.metadata)
            delta_truth = fitting.covariance_truth(mset.metadata, data.scales)  # ΔΣ of its surface, if recorded
        except Exception as err:  # noqa: BLE001 — one material's failure is recorded, the library goes on
            records.append(_record(name, "failed", t0, error=_failure(err)))
            continue
        todo.append((name, data, model, info, truth, delta_truth))
    if not todo:
        return records
    t0 = time.perf_counter()
    fits = spec.fit_many([m for _, _, m, *_ in todo], [d for _, d, *_ in todo], batch=batch)
    fit_seconds = (time.perf_counter() - t0) / len(todo)
    problems = [fitting.Problem(m, d) for _, d, m, *_ in todo]
    # FitSpec's rule: a fit inadequate or undetermined before sampling is not sampled (unless spec.sample_inadequate)
    not_sampled = [
        None
        if isinstance(result, Exception)
        else spec.not_sampled_because(problem, result, covariance_truth=entry[5])  # the set's recorded ΔΣ too
        for entry, problem, result in zip(todo, problems, fits, strict=True)
    ]
    draws = [None] * len(todo)
    if spec.batched:
        # the gradient samplers vectorise: every material's chains in one program per bucket
        # (fitting.sample_many, equal to fitting.sample per material); the others sample per material below
        wanted = [k for k, result in enumerate(fits) if not_sampled[k] is None and not isinstance(result, Exception)]
        if wanted:
            drawn = spec.sample_many([problems[k] for k in wanted], [fits[k] for k in wanted], batch=batch)
            for k, d in zip(wanted, drawn, strict=True):
                draws[k] = d
    for (name, data, model, info, truth, delta_truth), problem, result, drawn, reason in zip(
        todo, problems, fits, draws, not_sampled, strict=True
    ):
        t1 = time.perf_counter()
        if isinstance(result, Exception) or isinstance(drawn, Exception):
            records.append(
                _record(name, "failed", t1, error=_failure(result if isinstance(result, Exception) else drawn))
            )
            continue
        partial, final = partial_directory(out, name), material_directory(out, name)
        try:
            os.makedirs(partial, exist_ok=True)
            with exclusive(partial, what="material directory"):
                samples = drawn
                if spec.sampler is not None and not spec.batched and reason is None:  # resumable: its checkpoint
                    samples = spec.sample(problem, result, checkpoint=os.path.join(partial, "chain.h5"), progress=False)
                doc = fitting.write_report(
                    partial,
                    problem,
                    result,
                    samples,
                    truth=truth,
                    model_info=info,
                    overwrite=True,
                    figures=spec.figures,
                    covariance_truth=delta_truth,
                    not_sampled=reason,
                )
            try:
                os.rename(partial, final)
            except OSError:
                if os.path.isdir(final) and report_problem(final) is None:  # another attempt finished it first
                    shutil.rmtree(partial, ignore_errors=True)
                    records.append(_record(name, "skipped", t1))
                    continue
                raise
        except OutputWriteError:  # a full disk is not this material's failure: the run stops, saying so
            raise
        except OutputInUseError as err:  # another live attempt holds this material
            records.append(_record(name, "failed", t1, error=_failure(err)))
            continue
        except OSError as err:  # creating or renaming the material's directory
            failure = write_failed(partial, err, step="moving the material's report into place")
            if failure.disk_full:
                raise failure from err
            records.append(_record(name, "failed", t1, error=_failure(err)))
            continue
        except Exception as err:  # noqa: BLE001
            records.append(_record(name, "failed", t1, error=_failure(err)))
            continue
        mcmc = doc.get("mcmc") or {}
        records.append(
            _record(
                name,
                "done",
                t1,
                fit_seconds=round(fit_seconds, 4),
                chi2=result.chi2,
                reduced_chi2=result.chi2 / result.dof,
                fit_status=result.status,
                undetermined=[u["combination"] for u in result.undetermined],
                sampler_status=mcmc.get("status"),
            )
        )
    return records
