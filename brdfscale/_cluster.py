"""Ray for work split into tasks — a library's batches of materials (:mod:`brdfscale.library`), a measurement's
batches of rays (:mod:`brdfscale.instrument`): the one place that picks the executor, starts or joins Ray (the
optional extra ``brdfscale[cluster]``), stops what it started, and maps a function over tasks on it.

* :func:`resolve_executor` — ``"auto"``/``"process"``/``"ray"`` and ``address``/``workers`` checked, ``"auto"``
  resolved (Ray when either is given); :func:`check_options` — ``workers``, ``cpus_per_task``, ``retries`` checked;
* :func:`ray_session` — Ray initialised for a run: the cluster at ``address``, or a local instance of ``workers`` CPUs
  started here and stopped at the end, also when this process dies first (the watchdog,
  :mod:`brdfscale._watchdog`); a Ray the caller initialised is used as it is and left running;
* :func:`as_completed` — ``function(shared, item)`` for every item as Ray tasks, ``shared`` put into Ray's object
  store once, the results yielded as they arrive with their item's index.

Nothing here imports Ray until called.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from ._choices import EXECUTORS
from ._errors import InvalidInputError, MissingDependencyError


def resolve_executor(executor, address, workers) -> str:
    """``"process"`` or ``"ray"``: ``executor`` checked (:data:`brdfscale.choices.EXECUTORS`) and ``"auto"``
    resolved; ``address`` and ``workers`` (Ray's) refused in-process. InvalidInputError naming what is accepted."""
    EXECUTORS.check(executor)
    if address is not None and not isinstance(address, str):
        raise InvalidInputError(
            "address must be a Ray cluster's address (e.g. 'auto' or 'HOST:6379') or None; "
            f"got {type(address).__name__}."
        )
    if executor == "auto":
        return "ray" if (address or workers) else "process"
    if executor == "process" and (address or workers):
        raise InvalidInputError("address and workers are Ray's: use executor='ray' (or 'auto').")
    return executor


def check_options(workers, cpus_per_task, retries) -> tuple[int | None, float, int]:
    """``(workers, cpus_per_task, retries)`` checked: ``workers`` None or an integer ≥ 1 (CPUs of a local Ray
    instance), ``cpus_per_task`` a real > 0 (the CPUs Ray reserves for a task), ``retries`` an integer ≥ 0 (Ray's
    retries of a task whose worker died). InvalidInputError naming what is accepted."""
    from ._validation import integer, real

    return (
        None if workers is None else integer(workers, "workers", 1),
        real(cpus_per_task, "cpus_per_task", minimum=0, strict=True),
        integer(retries, "retries", 0),
    )


@contextlib.contextmanager
def _sigterm_kept() -> Iterator[None]:
    """The process's SIGTERM handler as it was before, once the block ends: ``ray.init`` replaces it (with
    ``sys.exit``) and ``ray.shutdown`` leaves Ray's in place, a change of the caller's process that outlives the run.
    Only the main thread can set a handler (elsewhere Ray does not set one either)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.getsignal(signal.SIGTERM)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before if before is not None else signal.SIG_DFL)


@contextlib.contextmanager
def ray_session(address: str | None, workers: int | None, *, instead: str):
    """Ray, initialised for the run: connected to the cluster at ``address``, or a local instance with ``workers``
    CPUs (None: the machine's) started here and stopped at the end — by ``ray.shutdown()``, and, should this process
    die first (even by SIGKILL), by the watchdog (:mod:`brdfscale._watchdog`); the SIGTERM handler Ray installs is
    replaced by the caller's again at the end (``tests/test_cluster.py``). A Ray the caller initialised is used
    as it is and left running. Without Ray: MissingDependencyError naming the extra, and ``instead`` (what to do
    without it)."""
    try:
        import ray
    except ImportError:
        raise MissingDependencyError(
            f"executor='ray' needs Ray: pip install 'brdfscale[cluster]' (or {instead})."
        ) from None
    if ray.is_initialized():  # the caller's own Ray: used as it is, left running
        yield ray
        return
    options: dict[str, Any] = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
    if address:
        with _sigterm_kept():
            ray.init(address=address, **options)
            try:
                yield ray
            finally:
                ray.shutdown()  # disconnects; the cluster's processes are not this run's
        return
    watchdog = subprocess.Popen(
        [sys.executable, "-I", "-S", os.path.join(os.path.dirname(os.path.abspath(__file__)), "_watchdog.py")]
        + [str(os.getpid())],
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # outlives this process, and a kill of its process group
        close_fds=True,
    )
    try:
        with _sigterm_kept():
            ray.init(num_cpus=workers, **options)
            try:
                yield ray
            finally:
                ray.shutdown()
    finally:
        assert watchdog.stdin is not None
        watchdog.stdin.close()  # end of file: the watchdog stops what is left of the instance, and exits
        watchdog.wait()


def as_completed(
    ray, function: Callable, shared, items: Sequence, *, cpus_per_task: float = 1, retries: int = 2
) -> Iterator[tuple[int, Any]]:
    """``function(shared, item)`` for every item as a Ray task (``cpus_per_task`` CPUs, ``retries`` retries of a task
    whose worker died; an exception the function raises is not retried), ``shared`` put into the object store once;
    yields ``(index of the item, result)`` as each task completes. A task that failed raises here, as Ray's
    ``RayTaskError`` (its ``cause`` the function's exception) or a worker's death past its retries."""
    remote: Any = ray.remote  # Any: Ray's stubs type a task's .remote() without its keywords
    task = remote(num_cpus=cpus_per_task, max_retries=retries, retry_exceptions=False)(function)
    reference = ray.put(shared)
    pending = {task.remote(reference, item): k for k, item in enumerate(items)}
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        k = pending.pop(ready[0])
        yield k, ray.get(ready[0])
