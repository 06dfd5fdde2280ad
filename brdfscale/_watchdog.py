"""The watchdog of a local Ray instance: stops the Ray processes a driver (a library run, an instrument
measurement) started once that driver is gone, however it ended (SIGKILL included). Standard library only, run as a
script by path (``python -I -S _watchdog.py DRIVER_PID``) so that it starts in milliseconds
without importing brdfscale or JAX.

Why it is needed: Ray shares the fate of the processes it starts itself (the GCS server, the
raylet, the dashboard and log monitor get ``PR_SET_PDEATHSIG`` from the driver), but the
agents the raylet starts (``ray::DashboardAgent``, ``ray::RuntimeEnvAgent``) outlived a
``kill -9`` of the driver by minutes (measured with Ray 2.60: alive 30 s later, the
workers gone). ``tests/test_library_robustness.py`` measures that nothing of the run is left
a few seconds after the driver's SIGKILL.

How: :func:`brdfscale._cluster.ray_session` (for :func:`brdfscale.library.fit_library` and
:meth:`brdfscale.instrument.Measurement.measure`) starts this process in a session of its own, just
before ``ray.init``, with a pipe as its standard input whose writing end only the driver holds.
While the driver lives, every 0.2 s the watchdog records the driver's descendants that are Ray's
(a command line under Ray's package or named ``ray::…`` when first seen) and everything below
those, each with its start time. When the pipe reaches end of file — the driver closed it after
``ray.shutdown()``, or the kernel closed it because the driver died — the watchdog adds every
process holding a file of the driver's Ray session open (what the raylet started since the last
poll), sends
SIGTERM to every recorded process that still runs with the same start time (a PID reused by an
unrelated process is left alone), SIGKILL two seconds later to what remains, and exits.
"""

import os
import re
import select
import signal
import sys
import time


def process_stat(pid: int) -> tuple[int, int] | None:
    """(parent PID, start time in clock ticks since boot) of ``pid`` from ``/proc/PID/stat``, or
    None when it is gone or a zombie. The one reader of the process table for the watchdog and
    for the tests and the fuzz study that check a killed run leaves no process behind."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            text = f.read()
    except OSError:
        return None
    fields = text[text.rfind(b")") + 2 :].split()
    if fields[0] in (b"Z", b"X"):
        return None
    return int(fields[1]), int(fields[19])


def _is_ray(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            command = f.read()
    except OSError:
        return False
    return command.startswith(b"ray::") or (os.sep + "ray" + os.sep).encode() in command


def _children() -> dict[int, list[int]]:
    tree: dict[int, list[int]] = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            stat = process_stat(int(name))
            if stat is not None:
                tree.setdefault(stat[0], []).append(int(name))
    return tree


def descendants(pid: int) -> dict[int, int]:
    """The live descendants of ``pid``, at any depth: PID → start time (clock ticks since boot)."""
    tree = _children()
    found: dict[int, int] = {}
    stack = [pid]
    while stack:
        for child in tree.get(stack.pop(), []):
            if child not in found and (start := process_stat(child)) is not None:
                found[child] = start[1]
                stack.append(child)
    return found


def alive(processes: dict[int, int]) -> list[int]:
    """Those of ``processes`` (PID → start time) still running: the same PID with the same start
    time (a PID reused by an unrelated process is not theirs)."""
    return [pid for pid, start in processes.items() if (process_stat(pid) or (0, None))[1] == start]


def _track(driver: int, tracked: dict[int, int]) -> None:
    """Add the driver's Ray descendants, and everything below them, to ``tracked`` (PID → start)."""
    tree = _children()
    stack = [(pid, False) for pid in tree.get(driver, [])]
    while stack:
        pid, below_ray = stack.pop()
        if pid == os.getpid():
            continue
        ours = below_ray or pid in tracked or _is_ray(pid)
        if ours and pid not in tracked:
            stat = process_stat(pid)
            if stat is None:
                continue
            tracked[pid] = stat[1]
        stack.extend((child, ours) for child in tree.get(pid, []))


def _session_processes(driver: int, tracked: dict[int, int]) -> None:
    """Add to ``tracked`` every process holding a file of the driver's Ray session open (its
    logs): ``…/session_DATE_TIME_MICROSECONDS_DRIVERPID/``. This finds what the raylet started
    in the last instants before the driver died, between two of :func:`_track`'s polls."""
    mark = re.compile(rf"{re.escape(os.sep)}session_[0-9_-]+_{driver}{re.escape(os.sep)}")
    for name in os.listdir("/proc"):
        if not name.isdigit() or int(name) in tracked or int(name) in (os.getpid(), driver):
            continue  # the driver holds its own log there: after ray.shutdown() it is waiting for this process
        try:
            links = [os.readlink(f"/proc/{name}/fd/{fd}") for fd in os.listdir(f"/proc/{name}/fd")]
        except OSError:
            continue
        if any(mark.search(link) for link in links):
            stat = process_stat(int(name))
            if stat is not None:
                tracked[int(name)] = stat[1]


def _stop(tracked: dict[int, int]) -> None:
    for sig, wait in ((signal.SIGTERM, 2.0), (signal.SIGKILL, 1.0)):
        for pid in alive(tracked):
            try:
                os.kill(pid, sig)
            except OSError:
                pass
        deadline = time.monotonic() + wait
        while alive(tracked) and time.monotonic() < deadline:
            time.sleep(0.05)


def main(driver: int) -> None:
    if not os.path.isdir("/proc"):  # Linux's process table is what it reads; elsewhere Ray's own clean-up only
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C of the terminal is the driver's to handle
    tracked: dict[int, int] = {}
    while True:
        _track(driver, tracked)
        ready, _, _ = select.select([0], [], [], 0.2)
        if ready and not os.read(0, 4096):  # end of file: the driver is done or dead
            break
    _session_processes(driver, tracked)
    _stop(tracked)


if __name__ == "__main__":
    main(int(sys.argv[1]))
