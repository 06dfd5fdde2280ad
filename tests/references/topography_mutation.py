"""Damaged instrument files and what they should read as, independently of brdfscale's reader.

The six instrument files of tests/data/topographies (Bruker ``.di``, FRT ``.frt``, Molecular
Imaging ``.mi``, Veeco ``.opd``, Sensofar ``.plu``, MountainsMap ``.mnt``) mutated byte by byte
(:func:`mutate`), and the verdict on reading one with :func:`brdfscale.topography.read`
(:func:`read_outcome`): ``refused`` (MeasurementFileError naming the file in one line),
``same`` (the undamaged field bit for bit, :func:`same_field`), ``faithful`` (exactly what
SurfaceTopography decodes from the damaged file — the oracle, :func:`faithful` — with finite
Σ(μ)) or ``bad``. :func:`write_ascii` writes a height map as a text file SurfaceTopography reads.

Used by tests/test_topography_robustness.py and by the fuzz family experiments/_fuzz_topography.py
(issue 34), which counts these verdicts over many mutants.
"""

import contextlib
import io
import os
import warnings
from pathlib import Path

import numpy as np


DATA = Path(__file__).resolve().parent.parent / "data" / "topographies"
FILES = ("di-3.di", "frt-1.frt", "mi-1.mi", "opd-1.opd", "plu-1.plu", "mnt-1.mnt")
BYTE_KINDS = ("bit_flip", "byte_set", "truncate", "insert", "header")
HEADER = 4096
HEADER_BYTES = b"0123456789+-.eE \t\n\r:=;,\x00"


def mutate(data: bytes, kind: str, rng: np.random.Generator) -> bytes:
    """One mutation of ``kind`` of ``data``, drawn from ``rng``."""
    b = bytearray(data)
    n = len(b)
    near = kind == "header" or rng.random() < 0.5
    i = int(rng.integers(min(n, HEADER) if near else n))
    if kind == "bit_flip":
        b[i] ^= 1 << int(rng.integers(8))
    elif kind == "byte_set":
        b[i] = int(rng.integers(256))
    elif kind == "header":
        b[i] = HEADER_BYTES[int(rng.integers(len(HEADER_BYTES)))]
    elif kind == "truncate":
        del b[i:]
    elif kind == "insert":
        b[i:i] = rng.integers(0, 256, int(rng.integers(1, 17))).astype(np.uint8).tobytes()
    else:
        raise ValueError(kind)
    return bytes(b)


def _measured(field) -> np.ndarray:
    return np.ones(field.shape, bool) if field.mask is None else field.mask


def same_field(a, b) -> bool:
    """Heights, mask and pitch bit for bit."""
    return (
        a.shape == b.shape
        and a.spacing == b.spacing
        and np.array_equal(a.heights, b.heights)
        and np.array_equal(_measured(a), _measured(b))
    )


def faithful(path: str, field) -> bool:
    """Whether ``field`` (read with ``detrend=None``) is what SurfaceTopography decodes from ``path``."""
    import SurfaceTopography as st

    from brdfscale import topography

    topo = st.open_topography(path).topography(channel_index=field.description["channel"]["index"])
    h = topo.heights()
    data = np.asarray(np.ma.getdata(h), dtype=float).T
    mask = ~np.isnan(data) & (~np.ma.getmaskarray(h).T if np.ma.isMaskedArray(h) else True)
    heights = np.where(mask, data * topography.UNITS[topo.unit], 0.0)
    (nx, ny), (lx, ly) = topo.nb_grid_pts, topo.physical_sizes
    scale = topography.UNITS[topo.unit]
    pitch, _ = topography.square_pitch(lx / nx * scale, ly / ny * scale)
    measured = mask if field.mask is None else field.mask
    return (
        heights.shape == field.shape
        and np.array_equal(mask, measured)
        and np.allclose(field.spacing, pitch, rtol=1e-15, atol=0)
        and np.array_equal(np.where(measured, field.heights, 0.0), heights)
    )


def finite_statistics(field) -> bool:
    """Σ(μ) finite at the smallest and the largest default scale (a field with no admissible
    window is refused by the library's InvalidInputError, which is an answer too)."""
    from brdfscale import InvalidInputError, synth

    try:
        stats = synth.facet_statistics(field, field.scales(2), bins=9)
    except InvalidInputError:
        return True
    return all(np.all(np.isfinite(s.covariance)) for s in stats)


def read_outcome(path: str, reference) -> tuple[str, str]:
    """``("refused" | "same" | "faithful" | "bad", why)`` for one (damaged) file."""
    from brdfscale import MeasurementFileError, topography

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            field = topography.read(path, detrend=None)
            verdict = (
                "same"
                if same_field(field, reference)
                else "faithful"
                if faithful(path, field) and finite_statistics(field)
                else "bad"
            )
            why = "" if verdict != "bad" else "read a field that is neither the undamaged one nor the file's content"
        except MeasurementFileError as err:
            verdict, why = "refused", str(err)
            if "\n" in why.strip() or os.path.basename(path) not in why:
                verdict, why = "bad", f"message not one line naming the file: {why[:120]!r}"
        except Exception as err:  # noqa: BLE001 — any other exception is the failure this study looks for
            verdict, why = "bad", f"{type(err).__name__}: {' '.join(str(err).split())[:160]}"
    if out.getvalue().strip() and verdict != "bad":
        verdict, why = "bad", f"printed while reading: {out.getvalue().strip()[:120]!r}"
    return verdict, why


def write_ascii(path: str, heights: np.ndarray, pitch_x_m: float, pitch_y_m: float) -> None:
    """A height map (rows y, metres) as a text file SurfaceTopography reads (AscReader)."""
    ny, nx = heights.shape
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"# Channel: Z\n# Width: {nx * pitch_x_m!r} m\n# Height: {ny * pitch_y_m!r} m\n# Value units: m\n")
        np.savetxt(f, heights, fmt="%.17g")
