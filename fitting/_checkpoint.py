"""The HDF5 checkpoint of :func:`fitting.sample`: one layout for every sampler, resumable bit for bit, checked.

Layout (format ``FORMAT``; every array float64 unless stated, ``W`` trajectories — the
walkers of all emcee ensembles, or one per chain of NUTS/HMC — and ``d`` coordinates θ):

* attribute ``format``; attribute ``signature``: JSON of what makes a chain this run's (the
  coordinates' names, the sampler and its settings, the chains, the trajectories, a digest
  of the problem, the seed, the sampling coordinates); attribute ``header``: the SHA-256 of
  the format, the signature, the layout (W, d, the chunk length, the statistics' names and
  dtypes) and the subspace's arrays; attribute ``steps_done``: the number of completed
  steps, written last — the commit marker;
* ``chain`` (step, W, d): θ of every trajectory after every step (warm-up steps included);
* ``log_prob`` (step, W): log p(θ | data) = −½χ²(θ) + const (the θ-density, without the Jacobian);
* ``stats/NAME`` (step, W): per-step statistics of the sampler (NUTS/HMC: acceptance_rate,
  divergent, integration_steps, step_size);
* ``subspace/``: the sampled subspace of z (``origin`` (d,), ``basis`` (d, m);
  :class:`fitting._posterior.Target`), written when the file is created: a resumed run samples
  that very posterior, even from a refit that differs in the last bits;
* ``state/NAME`` (chunk, …): the sampler's state after each committed chunk (the positions ζ
  in the sampled subspace, their log-density and gradient, the random state or PRNG key data,
  the adaptation state) — one row per chunk, so that a run can restart after any good chunk;
* ``chunks/end`` (chunk,) int64: the step after each chunk's last; ``chunks/digest`` (chunk,)
  64-byte ASCII: the chunk's SHA-256 (:func:`_chunk_digest`) over its steps' bytes in
  ``chain``, ``log_prob`` and every ``stats/NAME``, its state row, its end, and the digest
  before it (the header's for the first chunk): a hash chain, so a chunk cannot be altered,
  dropped or reordered without the check failing.

An append writes the chunk's state row, its block of steps, its end and digest, flushes, and
only then moves ``steps_done`` to the chunk's end: a kill at any moment before the commit
leaves the committed chunks intact (rows beyond the commit are ignored and overwritten), and
the resumed run continues from the last of them.

Verification (:meth:`Checkpoint.load`, on every resume and every read of a finished chain):
the header digest, then each committed chunk's digest recomputed from the bytes read back,
then NaN or infinity in the chain, the statistics or the state (−∞ is a log-density's
legitimate value; NaN and +∞ are not). The first chunk that fails is named with its steps, and
the message says what to do: keep the chunks before it and continue with
:func:`rewind_checkpoint` (they verify, and the continued run yields the undamaged run's chain
bit for bit), or start again with ``overwrite=True``. A file HDF5 cannot open or whose header
fails has no good chunk. Nothing that fails a check is ever resumed into a result.

Writes: every h5py write is checked at the h5py boundary (:func:`_h5_write`; the file's
creation and :func:`rewind_checkpoint` go through :func:`brdfscale.files.atomic_write`): its
errors — a full disk, an I/O error — become :class:`brdfscale.OutputWriteError` naming the file
and the free space (``brdfscale fit`` exits 8), and the committed chunks are kept. The free
space is checked before each chunk (the chunk's bytes as HDF5's whole chunks, plus a margin,
:func:`_need`; :func:`brdfscale.files.require_free_space`), so that HDF5 is not driven into a
full disk, whose failures can leave its library state unusable. HDF5's chunk cache is off for
these writes (``rdcc_nbytes=0``): a chunk that cannot be written fails where it is written, not
later when HDF5 releases its objects, where h5py could only print the error (tested on a real,
full tmpfs with the free-space check switched off: the library's error, no HDF5 dump, no crash).
A new file (:meth:`Checkpoint.create`, :func:`rewind_checkpoint`) is written to a temporary
beside the checkpoint, read back and verified, and only then moved into place.
"""

import contextlib
import errno
import hashlib
import json
import os

import numpy as np

from brdfscale import BrdfscaleError, files, InvalidInputError, MeasurementFileError


__all__ = ["FORMAT", "Checkpoint", "Stored", "rewind_checkpoint"]

FORMAT = "brdfscale.fitting.sample/3"
_EARLIER = {
    "brdfscale.fitting.sample/2": "its chunks carry no checksums, so what it holds cannot be verified",
    None: "one emcee ensemble sampled in θ, without the samplers' common layout",
}
_EXPECTED = "an HDF5 checkpoint written by fitting.sample"
_REWIND = "fitting.rewind_checkpoint(path)"
"""How a refusal names the remedy that keeps a damaged checkpoint's verified chunks (the path is
named at the start of the message); the command line says ``--rewind-checkpoint`` instead
(``brdfscale._cli.FLAGS``)."""
_MARGIN = 1 << 20  # bytes beyond a chunk's own that must be free before it is written (HDF5's metadata)
_FOREIGN = (RuntimeError, ValueError, KeyError, TypeError)  # h5py's failures that are not OSError
_KEPT = "the chunks committed before this write are kept (a rerun continues from them)"
#: What h5py raises on a damaged file (HDF5's errors surface as any of these).
_READ_ERRORS = (OSError, KeyError, ValueError, TypeError, RuntimeError, AttributeError, IndexError, UnicodeDecodeError)
_LOG_DENSITIES = ("log_prob", "log_density", "logdensity")  # where −∞ (zero density) is a legitimate value


def _h5py():
    """h5py, imported on first use."""
    import h5py

    return h5py


@contextlib.contextmanager
def _h5_write(path: str, step: str):
    """The h5py boundary of a write: any exception h5py raises (OSError; RuntimeError, ValueError,
    KeyError or TypeError from HDF5's state after a failure) becomes the library's
    :class:`brdfscale.OutputWriteError` naming the file and the free space."""
    try:
        yield
    except BrdfscaleError:
        raise
    except (OSError, RuntimeError, ValueError, KeyError, TypeError) as err:
        raise files.write_failed(path, err, step=step, kept=_KEPT) from None


def _need(chunk: int, rows: int, arrays) -> int:
    """Bytes a chunk of ``rows`` steps may need: HDF5 allocates whole chunks of ``chunk`` steps,
    and a block may straddle two of them, plus the state row and a margin."""
    per_step = sum(a.nbytes // max(a.shape[0], 1) for a in arrays[:-1])
    return 2 * max(chunk, rows) * per_step + arrays[-1] + _MARGIN


def _check_space(path: str, need: int) -> None:
    files.require_free_space(path, need, what="next chunk of the checkpoint")


def _update(h, name: str, a: np.ndarray | np.generic) -> None:
    """Feed ``name``, the dtype, the shape and the bytes of ``a`` (an array, or a NumPy scalar as
    h5py reads one row of a one-dimensional dataset) to the hash ``h``."""
    a = np.asarray(a)
    h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
    h.update(np.ascontiguousarray(a).tobytes())


def _header_digest(signature: str, W: int, d: int, chunk: int, stats: dict, subspace: dict) -> str:
    """SHA-256 of what a checkpoint is before its first chunk (module docstring)."""
    h = hashlib.sha256(FORMAT.encode())
    h.update(signature.encode())
    h.update(json.dumps([W, d, chunk, sorted((k, np.dtype(v).str) for k, v in stats.items())]).encode())
    for name in ("origin", "basis"):
        _update(h, name, np.asarray(subspace[name], dtype="f8"))
    return h.hexdigest()


def _chunk_digest(previous: str, end: int, blocks: list, state: dict) -> str:
    """SHA-256 of one chunk: the digest before it, its end, its steps' ``blocks`` ((name, array)
    in the datasets' dtypes) and its ``state`` row (name → array, in the datasets' dtypes)."""
    h = hashlib.sha256(previous.encode())
    h.update(str(int(end)).encode())
    for name, block in blocks:
        _update(h, name, block)
    for name in sorted(state):
        _update(h, "state/" + name, state[name])
    return h.hexdigest()


def _non_finite(name: str, a: np.ndarray | np.generic) -> bool:
    """NaN anywhere, or infinity other than a log-density's −∞, in a float array."""
    if not np.issubdtype(a.dtype, np.floating):
        return False
    bad = ~np.isfinite(a)
    if name.split("/")[-1] in _LOG_DENSITIES:
        bad &= a != -np.inf
    return bool(np.any(bad))


def _reads_back(tmp: str) -> None:
    """A checkpoint just written to the temporary ``tmp`` verifies, before it is moved into place:
    HDF5 reports some failed writes only when its objects are released, not to the caller."""
    try:
        verify(tmp)
    except (MeasurementFileError, InvalidInputError) as err:
        raise OSError(errno.EIO, f"the file written does not read back ({err})") from None


class Stored:
    """What a checkpoint holds: ``steps`` completed, the chain, log-probabilities and
    statistics of those steps, and the sampler's ``state`` after the last (None when 0 steps)."""

    def __init__(self, steps, chain, log_prob, stats, state, subspace):
        self.steps, self.chain, self.log_prob, self.stats, self.state = steps, chain, log_prob, stats, state
        self.subspace = subspace


def resumed_blocks(resumed: "Stored | None", steps: int) -> tuple[list, dict | None]:
    """A resumed run's first ``steps`` stored steps as one block (θ, log p(θ), statistics) and the sampler's
    carry after the last, as host arrays; ``([], None)`` when there is nothing to resume (no checkpoint, or one
    with no step done). What the chain-driving samplers (:class:`fitting.NUTS`, :class:`fitting.HMC`,
    :class:`fitting.IMH`) continue from."""
    if resumed is None or resumed.steps == 0:
        return [], None
    block = (resumed.chain[:steps], resumed.log_prob[:steps], {k: v[:steps] for k, v in resumed.stats.items()})
    return [block], {k: np.asarray(v) for k, v in resumed.state.items()}


class _Damaged(Exception):
    """A check failed: ``reason``; ``good`` steps (whole chunks before the failure) verify."""

    def __init__(self, reason: str, good: int | None):
        super().__init__(reason)
        self.reason, self.good = reason, good


def _read(f, path: str, stats_names, signature: str | None = None):
    """Everything a checkpoint's committed chunks hold, verified (module docstring): (Stored, ends,
    digests, state rows, layout). Raises _Damaged naming the first failure and the good steps,
    InvalidInputError for another run's or an earlier layout's file."""
    h5 = _h5py()
    attrs = f.attrs
    if attrs.get("signature") is None or "steps_done" not in attrs or not {"chain", "log_prob"} <= set(f):
        raise MeasurementFileError(
            f"{path} is not {_EXPECTED} (it lacks the signature, steps_done, chain or log_prob entries); use "
            "another path, or pass overwrite=True to start afresh."
        )
    fmt = attrs.get("format")
    if fmt != FORMAT:
        if fmt in _EARLIER or not isinstance(fmt, str):
            what = _EARLIER.get(fmt if isinstance(fmt, str) else None, _EARLIER[None])
            raise InvalidInputError(
                f"checkpoint {path} was written by an earlier version of fitting.sample ({what}) and cannot be "
                "continued by this one; use another path, or pass overwrite=True to start afresh."
            )
        raise _Damaged(f"its format attribute reads {fmt!r}, not {FORMAT!r}", None)
    stored_signature = attrs["signature"]
    if signature is not None and stored_signature != signature:
        raise InvalidInputError(
            f"checkpoint {path} belongs to a different run (its record: {stored_signature}; this run: "
            f"{signature}); use another path or pass overwrite=True."
        )
    try:
        chain_ds = f["chain"]
        if not isinstance(chain_ds, h5.Dataset) or chain_ds.ndim != 3 or chain_ds.chunks is None:
            raise TypeError("chain is not a chunked (step, W, d) dataset")
        _, W, d = chain_ds.shape
        chunk = chain_ds.chunks[0]
        names = sorted(f["stats"]) if stats_names is None else list(stats_names)
        stats_ds = {name: f[f"stats/{name}"] for name in names}
        subspace = {name: f[f"subspace/{name}"][()] for name in ("origin", "basis")}
        header = attrs.get("header")
        dtypes = {name: ds.dtype for name, ds in stats_ds.items()}
        if not isinstance(header, str) or not isinstance(stored_signature, str):
            raise TypeError("the header digest or the signature is not a string")
        expected = _header_digest(stored_signature, W, d, chunk, dtypes, subspace)
        if header != expected:
            raise ValueError("the header (signature, layout, subspace) fails its SHA-256 check")
        done = attrs["steps_done"]
        if not isinstance(done, (int, np.integer)) or done < 0:
            raise TypeError(f"steps_done is {done!r}, not a count")
        done = int(done)
    except _READ_ERRORS as err:
        raise _Damaged(str(err), None) from None
    if done == 0:
        stored = Stored(
            0,
            np.empty((0, W, d)),
            np.empty((0, W)),
            {k: np.empty((0, W), dtype=v) for k, v in dtypes.items()},
            None,
            subspace,
        )
        return stored, np.empty(0, np.int64), [], {}, (W, d, chunk, dtypes, stored_signature, header)
    try:
        ends = np.asarray(f["chunks/end"][()], dtype=np.int64)
        digests = [bytes(x).decode("ascii") for x in f["chunks/digest"][()]]
        committed = np.flatnonzero(ends == done)
        if committed.size == 0:
            raise ValueError(f"no chunk ends at steps_done = {done}")
        rows = int(committed[0]) + 1
        ends, digests = ends[:rows], digests[:rows]
        state_rows = {name: ds[:rows] for name, ds in f["state"].items()}
    except _READ_ERRORS as err:
        raise _Damaged(f"its table of chunks cannot be read ({err})", 0) from None
    if not state_rows:
        raise _Damaged("it holds no sampler state", 0)
    previous, start, good = header, 0, 0
    try:
        arrays = {"chain": chain_ds, "log_prob": f["log_prob"], **{f"stats/{k}": v for k, v in stats_ds.items()}}
    except _READ_ERRORS as err:
        raise _Damaged(f"its datasets cannot be read ({err})", 0) from None
    data = {name: [] for name in arrays}
    for j in range(rows):
        end = int(ends[j])
        where = f"chunk {j} (steps {start}–{end - 1})"
        if not start < end <= done:
            raise _Damaged(f"{where}: its end is out of order", good)
        try:
            blocks = [(name, ds[start:end]) for name, ds in arrays.items()]
            state = {name: rows_[j] for name, rows_ in state_rows.items()}
        except _READ_ERRORS as err:
            raise _Damaged(f"{where} cannot be read ({err})", good) from None
        if any(b.shape[0] != end - start for _, b in blocks):
            raise _Damaged(f"{where}: its datasets are shorter than steps_done = {done}", good)
        digest = _chunk_digest(previous, end, blocks, state)
        if digest != digests[j]:
            raise _Damaged(f"{where} fails its SHA-256 check (its bytes changed after they were written)", good)
        bad = [name for name, b in blocks + [("state/" + k, v) for k, v in state.items()] if _non_finite(name, b)]
        if bad:
            raise _Damaged(f"{where} holds NaN or infinite values in {', '.join(bad)}", good)
        for name, b in blocks:
            data[name].append(b)
        previous, start, good = digest, end, end
    chain = np.concatenate(data["chain"])
    log_prob = np.concatenate(data["log_prob"])
    stats = {k: np.concatenate(data[f"stats/{k}"]) for k in stats_ds}
    state = {name: rows_[rows - 1] for name, rows_ in state_rows.items()}
    stored = Stored(done, chain, log_prob, stats, state, subspace)
    return stored, ends, digests, state_rows, (W, d, chunk, dtypes, stored_signature, header)


def _initialise(f, signature: str, W: int, d: int, chunk: int, stats: dict, subspace: dict) -> None:
    """The datasets and attributes of a checkpoint with no steps, in an open, empty HDF5 file."""
    f.create_dataset("chain", (0, W, d), maxshape=(None, W, d), chunks=(chunk, W, d), dtype="f8")
    f.create_dataset("log_prob", (0, W), maxshape=(None, W), chunks=(chunk, W), dtype="f8")
    group = f.create_group("stats")
    for name, dtype in stats.items():
        group.create_dataset(name, (0, W), maxshape=(None, W), chunks=(chunk, W), dtype=dtype)
    group = f.create_group("subspace")
    for name, value in subspace.items():
        group.create_dataset(name, data=np.asarray(value, dtype="f8"))
    group = f.create_group("chunks")
    group.create_dataset("end", (0,), maxshape=(None,), chunks=(64,), dtype="i8")
    group.create_dataset("digest", (0,), maxshape=(None,), chunks=(64,), dtype="S64")
    f.create_group("state")
    f.attrs["format"] = FORMAT
    f.attrs["signature"] = signature
    f.attrs["header"] = _header_digest(signature, W, d, chunk, stats, subspace)
    f.attrs["steps_done"] = 0


def _commit(f, blocks: list, state: dict) -> None:
    """Append one chunk — ``blocks`` ((dataset name, steps), the chain's first) and the ``state``
    after its last step — to an open checkpoint, its digest chained to the last committed
    chunk's, and commit it (steps_done last)."""
    h5 = _h5py()
    done = int(f.attrs["steps_done"])
    ends = f["chunks/end"]
    row = 0 if done == 0 else int(np.flatnonzero(ends[()] == done)[0]) + 1
    previous = f.attrs["header"] if row == 0 else bytes(f["chunks/digest"][row - 1]).decode("ascii")
    n = done + blocks[0][1].shape[0]
    stored_blocks = []
    for name, block in blocks:
        dataset = f[name]
        block = np.asarray(block, dtype=dataset.dtype)
        dataset.resize(n, axis=0)
        dataset[done:n] = block
        stored_blocks.append((name, block))
    group = f["state"]
    stored_state = {}
    for name, value in state.items():
        value = np.asarray(value)
        if name not in group:
            group.create_dataset(
                name, (0, *value.shape), maxshape=(None, *value.shape), chunks=(1, *value.shape), dtype=value.dtype
            )
        dataset = group[name]
        if not isinstance(dataset, h5.Dataset):
            raise TypeError(f"state/{name} is not a dataset")
        value = np.asarray(value, dtype=dataset.dtype)
        dataset.resize(row + 1, axis=0)
        dataset[row] = value
        stored_state[name] = value
    digest = _chunk_digest(previous, n, stored_blocks, stored_state)
    for name, value in (("end", n), ("digest", digest.encode("ascii"))):
        dataset = f["chunks/" + name]
        dataset.resize(row + 1, axis=0)
        dataset[row] = value
    f.flush()
    f.attrs["steps_done"] = n  # the commit marker, written last
    f.flush()


class Checkpoint:
    """An HDF5 file holding the chain so far and the sampler's state after each chunk (module docstring).

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
        """The completed steps, verified (module docstring), or None if there is no file.

        Raises:
            MeasurementFileError: the file is not a readable checkpoint of this layout, or damaged
                (the message names the first chunk that fails and how to continue).
            InvalidInputError: it belongs to another run, or to an earlier layout.
        """
        if not os.path.exists(self.path):
            return None
        stored, _ = verify(self.path, self.signature, self.stats)
        if stored.chain.shape[1:] != (self.walkers, self.d) or stored.subspace["basis"].shape != (self.d, self.m):
            raise MeasurementFileError(
                f"checkpoint {self.path} is damaged (its chain has shape {stored.chain.shape} and its subspace "
                f"{stored.subspace['basis'].shape}, where this run has {self.walkers} trajectories, {self.d} "
                f"coordinates and {self.m} sampled); use another path, or pass overwrite=True to start afresh."
            )
        return stored

    def create(self, replace: bool, subspace: dict):
        """A checkpoint with no steps and the run's ``subspace`` arrays, written atomically (a hidden
        temporary file in the same directory, moved into place); an existing file is replaced
        only when ``replace``."""

        def write(tmp):
            with _h5py().File(tmp, "w", rdcc_nbytes=0) as f:
                _initialise(f, self.signature, self.walkers, self.d, self.chunk, self.stats, subspace)
            _reads_back(tmp)

        _check_space(self.path, _MARGIN)
        files.atomic_write(self.path, write, overwrite=replace, error=MeasurementFileError, foreign=_FOREIGN)

    def append(self, chain, log_prob, stats: dict, state: dict):
        """Add a block of steps and the state after its last one (module docstring: the commit marker last)."""
        blocks = [("chain", np.asarray(chain)), ("log_prob", np.asarray(log_prob))]
        blocks += [(f"stats/{k}", np.asarray(stats[k])) for k in self.stats]
        state_bytes = sum(np.asarray(v).nbytes for v in state.values())
        _check_space(self.path, _need(self.chunk, blocks[0][1].shape[0], [b for _, b in blocks] + [state_bytes]))
        f = None
        try:
            with _h5_write(self.path, "appending a chunk"):
                f = _h5py().File(self.path, "r+", rdcc_nbytes=0)  # chunks written at once: errors here, not later
                _commit(f, blocks, state)
                f.close()
                f = None
        finally:
            if f is not None:  # after a failed write: close without letting HDF5's own errors out
                with contextlib.suppress(Exception):
                    f.close()


def recorded_signature(path) -> dict | None:
    """The signature (module docstring) a checkpoint at ``path`` records, or None where there is no file or no
    readable signature — read without verifying the chunks: what :meth:`fitting.Auto.choose` continues from, before
    :meth:`Checkpoint.load` verifies the file and says what is wrong with one it cannot read."""
    if path is None or not os.path.isfile(path):
        return None
    try:
        with _h5py().File(path, "r") as f:
            text = f.attrs.get("signature")
        text = text.decode() if isinstance(text, bytes) else text
        return json.loads(text) if isinstance(text, str) else None
    except _READ_ERRORS:  # not HDF5, damaged, not JSON: load() names the fault
        return None


def verify(path, signature: str | None = None, stats=None) -> tuple[Stored, dict]:
    """The verified contents of the checkpoint ``path`` (module docstring) and its record
    (``signature``: the run's JSON record; ``steps``: steps committed).

    Raises:
        MeasurementFileError: it cannot be read, or it is damaged: the message names the first
            chunk that fails, the steps before it that verify, and what to do.
        InvalidInputError: it belongs to another run than ``signature`` (when given), or to an
            earlier layout.
    """
    path = os.fspath(path)
    retry = "pass overwrite=True to start afresh"
    try:
        f = _h5py().File(path, "r")
    except OSError as err:
        raise MeasurementFileError(
            f"checkpoint {path} cannot be read as {_EXPECTED} ({err}); use another path, or {retry}."
        ) from None
    try:
        with f:
            stored, _, _, _, layout = _read(f, path, stats, signature)
    except _Damaged as err:
        if err.good:
            remedy = (
                f"the steps before it (0–{err.good - 1}) verify: keep them and continue from step {err.good} with "
                f"{_REWIND} and run again, or {retry}"
            )
        else:
            remedy = f"no chunk of it can be kept; {retry}"
        raise MeasurementFileError(f"checkpoint {path} is damaged: {err.reason}; {remedy}.") from None
    except BrdfscaleError:
        raise  # another run's, an earlier layout's, not a checkpoint: said as such
    except _READ_ERRORS as err:  # HDF5's own structures damaged (or the file's closing failed)
        raise MeasurementFileError(
            f"checkpoint {path} is damaged ({err}); no chunk of it can be kept; {retry}."
        ) from None
    return stored, {"signature": json.loads(layout[4]), "steps": stored.steps}


def _good_chunks(f, good: int):
    """The layout of an open checkpoint whose header verified, and its chunks up to step ``good``
    (verified): ((signature, W, d, chunk, statistics' dtypes, subspace), the datasets' names, the
    kept chunks' ends, their steps per dataset, their state rows)."""
    chain_ds = f["chain"]
    _, W, d = chain_ds.shape
    dtypes = {name: ds.dtype for name, ds in sorted(f["stats"].items())}
    subspace = {name: f[f"subspace/{name}"][()] for name in ("origin", "basis")}
    keep = []
    if good:  # the good chunks' ends: the table's rows up to the one that ends at `good`
        ends = np.asarray(f["chunks/end"][()], dtype=np.int64)
        keep = [int(e) for e in ends[: int(np.flatnonzero(ends == good)[0]) + 1]]
    names = ["chain", "log_prob"] + [f"stats/{k}" for k in dtypes]
    data = {name: np.asarray(f[name][:good]) for name in names}
    states = {name: np.asarray(ds[: len(keep)]) for name, ds in f["state"].items()} if keep else {}
    layout = (str(f.attrs["signature"]), W, d, chain_ds.chunks[0], dtypes, subspace)
    return layout, names, keep, data, states


def rewind_checkpoint(path) -> int:
    """Keep the chunks of a damaged checkpoint that verify, drop the rest: a run of
    :func:`fitting.sample` on it then continues from the last good chunk, and yields the chain
    of an undamaged run bit for bit (its state after that chunk is in the file, and every
    step's randomness depends on the step only). The file is replaced atomically; a checkpoint
    that verifies whole is left as it is. Returns the steps kept.

    The command line's ``brdfscale fit … --rewind-checkpoint`` calls it on ``DIR/chain.h5``
    before sampling (tests/test_cli_rewind.py). It holds the checkpoint's lock
    (:func:`brdfscale.files.exclusive`), the one a sampling run holds.

    Raises:
        MeasurementFileError: no part of it can be kept (HDF5 cannot open it, or its header —
            signature, layout, sampled subspace — fails its check: start afresh with
            ``overwrite=True``), or it cannot be rewritten (the message names the free space).
        InvalidInputError: it is an earlier layout's checkpoint (it carries no checksums).
        OutputInUseError: a run is sampling into it.
    """
    path = os.fspath(path)
    with files.exclusive(path, what="checkpoint") if os.path.isfile(path) else contextlib.nullcontext():
        return _rewind(path)


def _rewind(path: str) -> int:
    h5 = _h5py()
    nothing = "nothing of it can be kept: pass overwrite=True to fitting.sample to start afresh."
    try:
        f = h5.File(path, "r")
    except OSError as err:
        raise MeasurementFileError(f"checkpoint {path} cannot be read as {_EXPECTED} ({err}); {nothing}") from None
    try:
        with f:
            try:
                stored = _read(f, path, None)[0]
                return stored.steps  # whole: nothing to drop
            except _Damaged as err:
                if err.good is None:
                    raise MeasurementFileError(
                        f"checkpoint {path} is damaged beyond its chunks ({err.reason}); {nothing}"
                    ) from None
                good = err.good
            layout, names, keep, data, states = _good_chunks(f, good)
    except BrdfscaleError:
        raise
    except _READ_ERRORS as err:
        raise MeasurementFileError(f"checkpoint {path} is damaged beyond its chunks ({err}); {nothing}") from None
    signature, W, d, chunk, dtypes, subspace = layout

    def write(tmp):
        with h5.File(tmp, "w", rdcc_nbytes=0) as out:
            _initialise(out, signature, W, d, chunk, dtypes, subspace)
            start = 0
            for row, end in enumerate(keep):
                _commit(
                    out,
                    [(name, data[name][start:end]) for name in names],
                    {name: rows[row] for name, rows in states.items()},
                )
                start = end
        _reads_back(tmp)

    _check_space(path, sum(a.nbytes for a in data.values()) * 2 + _MARGIN)
    files.atomic_write(path, write, overwrite=True, error=MeasurementFileError, foreign=_FOREIGN)
    return good
