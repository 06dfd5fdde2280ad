"""Work divided over devices — the one mechanism of :func:`fitting.fit_many` and :func:`fitting.sample_many`.

A batch (materials × starts of ``fit_many``, the materials of ``sample_many``) is divided along
its leading axis into equal, contiguous slices, one per device (:func:`split`); the same
compiled program runs on every slice by itself, dispatched device by device
(:func:`on_devices`) — where JAX dispatches asynchronously, as on GPUs, the devices compute at
once; JAX runs a CPU program in the calling thread, so on (virtual) CPU devices the slices
follow each other. No collective is needed: each device stops when its own slice is done (a
device's NUTS trees or Levenberg–Marquardt iterations never wait for another's). The outputs
come back joined on the host (:func:`joined`) or as one global ``jax.Array`` divided over the
devices as the inputs were (:func:`assembled`).

Why not XLA's SPMD partitioning or ``jax.shard_map``: SPMD partitioning of the jitted solve over
a ``NamedSharding`` deadlocked on 2 virtual CPU devices in a loop whose devices disagreed on the
trip count, from 24 solves up; ``shard_map`` is refused by lineax's structure check (it compares
a vector without the manual mesh to an operator structure with it; JAX 0.10, lineax 0.1.1), and
dispatching from one thread per device, to overlap the compilations too, hung on 2 virtual CPU
devices. JAX binds an executable to its device, so each device compiles the program, once per
process, one after another.

With one device nothing is moved or split: the program runs on the inputs as given, exactly as
without this module (the bit-identity tests of tests/test_batch.py and tests/test_sample_many.py).
"""

from collections.abc import Iterable

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from brdfscale import InvalidInputError


__all__ = ["Split", "assembled", "device_list", "joined", "on_devices", "split"]


def device_list(devices) -> list:
    """The devices of a ``devices=`` argument: ``None`` (every device of ``jax.devices()``), a
    count (the first ones), or a non-empty list of ``jax.Device``; InvalidInputError otherwise."""
    if devices is None:
        return jax.devices()
    if isinstance(devices, int) and not isinstance(devices, bool):
        available = jax.devices()
        if not 1 <= devices <= len(available):
            raise InvalidInputError(
                f"devices={devices}: this process has {len(available)} JAX device(s) "
                f"({available[0].platform}); give 1 … {len(available)} or a list of devices."
            )
        return available[:devices]
    devices = list(devices) if isinstance(devices, Iterable) else []
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        raise InvalidInputError(
            "devices must be None (all of jax.devices()), a count, or a non-empty list of jax.Device objects."
        )
    return devices


class Split(list):
    """A pytree divided over devices: entry k is the k-th contiguous slice of its leading axis,
    on device k (:func:`split`)."""


def split(tree, devices) -> Split:
    """``tree`` divided along the leading axis of every leaf into ``len(devices)`` equal slices,
    slice k placed on device k; with one device, ``tree`` itself (nothing moved)."""
    if len(devices) == 1:
        return Split([tree])
    per = jax.tree.leaves(tree)[0].shape[0] // len(devices)
    return Split(jax.device_put(_slice(tree, k * per, (k + 1) * per), device) for k, device in enumerate(devices))


def _slice(tree, start: int, stop: int):
    return jax.tree.map(lambda a: a[start:stop], tree)


def on_devices(fn, args, devices) -> list:
    """Dispatch ``fn(*args)`` once per device: an argument that is a :class:`Split` gives
    each device its own slice, any other is passed to every device as it is. Returns the runs
    (one output per device; where JAX dispatches asynchronously they are still computing)."""
    return [fn(*(a[k] if isinstance(a, Split) else a for a in args)) for k in range(len(devices))]


def joined(runs) -> tuple:
    """The outputs (tuples of arrays) of :func:`on_devices`'s runs joined on the host in order (NumPy)."""
    return tuple(np.concatenate([np.asarray(a) for a in column]) for column in zip(*runs))


_AXIS = "batch"


def assembled(runs, devices):
    """The outputs of :func:`on_devices`'s runs as one pytree of global ``jax.Array`` divided
    over the devices along the leading axis (slice k on device k, as :func:`split` gave them);
    with one device, its run as it is."""
    if len(devices) == 1:
        return runs[0]
    sharding = NamedSharding(Mesh(np.asarray(devices), (_AXIS,)), PartitionSpec(_AXIS))

    def one(*parts):
        shape = (sum(p.shape[0] for p in parts),) + parts[0].shape[1:]
        return jax.make_array_from_single_device_arrays(shape, sharding, list(parts))

    return jax.tree.map(one, *runs)
