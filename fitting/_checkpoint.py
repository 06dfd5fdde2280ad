"""The HDF5 checkpoint of :func:`fitting.sample`: one layout for every sampler, resumable bit for bit.

Layout (format ``FORMAT``; every array float64 unless stated, ``W`` trajectories — the
walkers of all emcee ensembles, or one per chain of NUTS/HMC — and ``d`` coordinates θ):

* attribute ``format``; attribute ``signature``: JSON of what makes a chain this run's (the
  coordinates' names, the sampler and its settings, the chains, the trajectories, a digest
  of the problem, the seed, the sampling coordinates); attribute ``steps_done``: the number
  of completed steps, written last — the commit marker;
* ``chain`` (step, W, d): θ of every trajectory after every step (warm-up steps included);
* ``log_prob`` (step, W): log p(θ | data) = −½χ²(θ) + const (the θ-density, without the Jacobian);
* ``stats/NAME`` (step, W): per-step statistics of the sampler (NUTS/HMC: acceptance_rate,
  divergent, integration_steps, step_size);
* ``subspace/``: the sampled subspace of z (``origin`` (d,), ``basis`` (d, m);
  :class:`fitting._posterior.Target`), written when the file is created: a resumed run samples
  that very posterior, even from a refit that differs in the last bits;
* ``state_0``, ``state_1``: two slots for the sampler's state after a step (the positions ζ
  in the sampled subspace, their log-density and gradient, the random state or PRNG key data, the adaptation
  state), each with an attribute ``step``. An append writes the slot that does *not* hold
  the committed state, then the chain's block, then ``steps_done``: a kill at any moment
  before the commit leaves the committed state intact, and the resumed run continues from
  it. A kill during the write of the datasets themselves can still damage the file (reported
  as such on the next load; HDF5 writes in place).

HDF5 datasets are chunked along the step axis with ``chunk`` steps per chunk. Temporary
files are written beside the checkpoint and moved into place (:func:`brdfscale.files.atomic_write`).
"""

import json
import os
from typing import TypeVar

import numpy as np

from brdfscale import InvalidInputError, MeasurementFileError
from brdfscale.files import atomic_write


__all__ = ["FORMAT", "Checkpoint", "Stored"]

FORMAT = "brdfscale.fitting.sample/2"
_EXPECTED = "an HDF5 checkpoint written by fitting.sample"


def _h5py():
    """h5py, imported on first use."""
    import h5py

    return h5py


_Node = TypeVar("_Node")


def _child(parent, name, kind: type[_Node]) -> _Node:
    """``parent[name]``, a dataset or a group as ``kind`` says: KeyError where it is absent,
    TypeError where it is the other kind of object (a damaged file)."""
    node = parent[name]
    if not isinstance(node, kind):
        raise TypeError(f"{name} is a {type(node).__name__}, not a {kind.__name__}")
    return node


def _count(node, name: str) -> int:
    """The integer attribute ``name`` of an HDF5 object: KeyError where it is absent, TypeError
    where it is not an integer (a damaged file)."""
    value = node.attrs[name]
    if not isinstance(value, (int, np.integer)):
        raise TypeError(f"attribute {name} is {value!r}, not an integer")
    return int(value)


class Stored:
    """What a checkpoint holds: ``steps`` completed, the chain, log-probabilities and
    statistics of those steps, and the sampler's ``state`` after the last (None when 0 steps)."""

    def __init__(self, steps, chain, log_prob, stats, state, subspace):
        self.steps, self.chain, self.log_prob, self.stats, self.state = steps, chain, log_prob, stats, state
        self.subspace = subspace


class Checkpoint:
    """An HDF5 file holding the chain so far and the sampler's state after the last chunk (module docstring).

    Args:
        path: the file.
        signature: JSON-able record of the run (a file with another record is refused).
        walkers: trajectories W; d: coordinates; chunk: the HDF5 chunk length in steps.
        stats: name → NumPy dtype of the per-step statistics; m: the sampled subspace's dimension.
    """

    def __init__(self, path, signature: dict, walkers: int, d: int, chunk: int, stats: dict, m: int):
        self.path, self.walkers, self.d, self.chunk, self.m = os.fspath(path), walkers, d, chunk, m
        self.signature, self.stats = json.dumps(signature, sort_keys=True), dict(stats)
        if os.path.isdir(self.path):
            raise MeasurementFileError(
                f"checkpoint {self.path} is a directory; expected the path of {_EXPECTED} (e.g. DIR/chain.h5)."
            )
        directory = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(directory):
            raise MeasurementFileError(
                f"checkpoint {self.path}: directory {directory} does not exist; create it "
                "or choose another checkpoint path."
            )

    def load(self) -> Stored | None:
        """The completed steps, or None if there is no file.

        Raises:
            MeasurementFileError: the file is not a readable checkpoint of this layout, or damaged.
            InvalidInputError: it belongs to another run, or to an earlier layout.
        """
        if not os.path.exists(self.path):
            return None
        retry = "use another path, or pass overwrite=True to start afresh."
        try:
            f = _h5py().File(self.path, "r")
        except OSError as err:
            raise MeasurementFileError(
                f"checkpoint {self.path} cannot be read as {_EXPECTED} ({err}); {retry}"
            ) from None
        with f:
            signature = f.attrs.get("signature")
            if signature is None or "steps_done" not in f.attrs or not {"chain", "log_prob"} <= set(f):
                raise MeasurementFileError(
                    f"{self.path} is not {_EXPECTED} (it lacks the signature, steps_done, "
                    f"chain or log_prob entries); {retry}"
                )
            if f.attrs.get("format") != FORMAT:
                raise InvalidInputError(
                    f"checkpoint {self.path} was written by an earlier version of fitting.sample (one emcee ensemble "
                    "sampled in θ, without the samplers' common layout) and cannot be continued by this one; "
                    f"{retry}"
                )
            if signature != self.signature:
                raise InvalidInputError(
                    f"checkpoint {self.path} belongs to a different run (its record: {signature}; this run: "
                    f"{self.signature}); use another path or pass overwrite=True."
                )
            try:
                h5 = _h5py()
                done = _count(f, "steps_done")
                chain, log_prob = _child(f, "chain", h5.Dataset)[:done], _child(f, "log_prob", h5.Dataset)[:done]
                stats = {name: _child(f, f"stats/{name}", h5.Dataset)[:done] for name in self.stats}
                subspace = {name: _child(f, f"subspace/{name}", h5.Dataset)[()] for name in ("origin", "basis")}
                state = None
                if done > 0:
                    slots = [
                        _child(f, s, h5.Group)
                        for s in ("state_0", "state_1")
                        if s in f and _count(f[s], "step") == done
                    ]
                    if not slots:
                        raise ValueError(f"no sampler state for step {done}")
                    state = {name: _child(slots[0], name, h5.Dataset)[()] for name in slots[0]}
            except (OSError, KeyError, ValueError, TypeError) as err:
                raise MeasurementFileError(f"checkpoint {self.path} is damaged ({err}); {retry}") from None
        shape = (done, self.walkers, self.d)
        if chain.shape != shape or log_prob.shape != shape[:2] or any(s.shape != shape[:2] for s in stats.values()):
            raise MeasurementFileError(
                f"checkpoint {self.path} is damaged (steps_done = {done}, but chain has shape "
                f"{chain.shape} and log_prob {log_prob.shape}); {retry}"
            )
        if subspace["origin"].shape != (self.d,) or subspace["basis"].shape != (self.d, self.m):
            raise MeasurementFileError(
                f"checkpoint {self.path} is damaged (its subspace has shapes "
                f"{subspace['origin'].shape}, {subspace['basis'].shape}); {retry}"
            )
        return Stored(done, chain, log_prob, stats, state, subspace)

    def create(self, replace: bool, subspace: dict):
        """A checkpoint with no steps and the run's ``subspace`` arrays, written atomically (a hidden
        temporary file in the same directory, moved into place); an existing file is replaced
        only when ``replace``."""
        W, d, chunk = self.walkers, self.d, self.chunk

        def write(tmp):
            with _h5py().File(tmp, "w") as f:
                f.create_dataset("chain", (0, W, d), maxshape=(None, W, d), chunks=(chunk, W, d), dtype="f8")
                f.create_dataset("log_prob", (0, W), maxshape=(None, W), chunks=(chunk, W), dtype="f8")
                group = f.create_group("stats")
                for name, dtype in self.stats.items():
                    group.create_dataset(name, (0, W), maxshape=(None, W), chunks=(chunk, W), dtype=dtype)
                group = f.create_group("subspace")
                for name, value in subspace.items():
                    group.create_dataset(name, data=np.asarray(value, dtype="f8"))
                f.attrs["format"] = FORMAT
                f.attrs["signature"] = self.signature
                f.attrs["steps_done"] = 0

        try:
            atomic_write(self.path, write, overwrite=replace, error=MeasurementFileError)
        except OSError as err:
            raise MeasurementFileError(f"checkpoint {self.path} cannot be written: {err}") from None

    def append(self, chain, log_prob, stats: dict, state: dict):
        """Add a block of steps and the state after its last one (the commit marker last)."""
        try:
            h5 = _h5py()
            with h5.File(self.path, "r+") as f:
                done = _count(f, "steps_done")
                n = done + chain.shape[0]
                free = next(
                    (s for s in ("state_0", "state_1") if s not in f or _count(f[s], "step") != done), "state_1"
                )
                if free in f:
                    del f[free]
                slot = f.create_group(free)
                for name, value in state.items():
                    slot.create_dataset(name, data=np.asarray(value))
                slot.attrs["step"] = n
                blocks = [("chain", chain), ("log_prob", log_prob)] + [(f"stats/{k}", v) for k, v in stats.items()]
                for name, block in blocks:
                    dataset = _child(f, name, h5.Dataset)
                    dataset.resize(n, axis=0)
                    dataset[done:n] = block
                f.flush()
                f.attrs["steps_done"] = n  # the commit marker, written last
        except OSError as err:
            raise MeasurementFileError(f"checkpoint {self.path} cannot be updated: {err}") from None
