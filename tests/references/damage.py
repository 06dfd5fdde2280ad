"""Damaged checkpoints and full disks, made independently of brdfscale's writers: where the
stored HDF5 chunks of a file lie (:func:`chunk_extents`, read through h5py's own chunk index),
bytes changed in place (:func:`overwrite`, :func:`flip_bit`), two sampler results compared bit
for bit (:func:`same_samples`), a tmpfs mounted (:func:`mount_tmpfs`) and a file system filled
until a given number of bytes is free (:func:`fill`, measured by ``os.statvfs``, not by
``brdfscale.files``).

Used by tests/test_checkpoint_integrity.py, tests/test_cli_rewind.py and tests/test_disk_full.py,
and by the fuzz families experiments/_fuzz_checkpoints.py and experiments/_fuzz_disk.py
(issue 34), which count the library's answers over many such damages.
"""

import contextlib
import os
import shutil
import subprocess
import sys

import numpy as np


def chunk_extents(path) -> dict[str, list[tuple[int, int]]]:
    """``(offset, size)`` in the file of every stored chunk of every chunked dataset of the HDF5
    file ``path``, in chunk order, by the dataset's name (``"chain"``, ``"stats/accepted"``, …)."""
    import h5py

    out: dict[str, list[tuple[int, int]]] = {}

    def visit(name, node):
        if isinstance(node, h5py.Dataset) and node.chunks is not None:
            infos = (node.id.get_chunk_info(i) for i in range(node.id.get_num_chunks()))
            out[name] = [(info.byte_offset, info.size) for info in infos]

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return out


def overwrite(path, offset: int, data: bytes) -> None:
    """Write ``data`` over the bytes of ``path`` from ``offset`` on, in place."""
    with open(path, "r+b") as f:
        f.seek(offset)
        f.write(data)


def flip_bit(path, offset: int, bit: int = 3) -> None:
    """Flip bit ``bit`` of the byte at ``offset`` of ``path``, in place."""
    with open(path, "rb") as f:
        f.seek(offset)
        byte = f.read(1)[0]
    overwrite(path, offset, bytes([byte ^ (1 << bit)]))


def same_samples(a, b) -> bool:
    """Whether two sampler results (``fitting.SampleResult``) hold the same chain, log-densities
    and statistics, bit for bit."""
    return (
        np.array_equal(a.chain, b.chain)
        and np.array_equal(a.log_prob, b.log_prob)
        and a.stats.keys() == b.stats.keys()
        and all(np.array_equal(a.stats[k], b.stats[k]) for k in a.stats)
    )


def mount_tmpfs(where, size: str) -> str | None:
    """Mount a tmpfs of ``size`` (``"1m"``, ``"192m"``) at the existing directory ``where``:
    None when mounted (``umount`` it when done), else why not (root on Linux is needed)."""
    if sys.platform != "linux" or not hasattr(os, "geteuid") or os.geteuid() != 0:
        return "a real full disk needs root on Linux (mount -t tmpfs)"
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", os.fspath(where)], capture_output=True)
    return None if r.returncode == 0 else f"mount -t tmpfs failed: {r.stderr.decode(errors='replace').strip()}"


def fill(directory, leave: int) -> str:
    """Fill ``directory``'s file system with a file ``directory/filler`` until ``leave`` bytes
    are free (0: until the kernel's ENOSPC); returns the filler's path (delete it to free the
    space again)."""
    filler = os.path.join(os.fspath(directory), "filler")
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        with contextlib.suppress(OSError):
            left = shutil.disk_usage(directory).free - leave
            while left > 0:
                left -= os.write(fd, b"\0" * min(left, 1 << 20))
            while leave == 0:
                os.write(fd, b"\0" * 4096)
    finally:
        os.close(fd)
    return filler
