"""Fuzz family ``topography`` (issue 34): damaged instrument files and hostile heights.

Damaged files. The six instrument files of tests/data/topographies (Bruker ``.di``, FRT
``.frt``, Molecular Imaging ``.mi``, Veeco ``.opd``, Sensofar ``.plu``, MountainsMap ``.mnt``)
are mutated and read with :func:`brdfscale.topography.read`, in turn:

* ``bit_flip`` / ``byte_set`` / ``truncate`` / ``insert`` — raw bytes anywhere in the file (half
  of them in its first 4 KiB, where the headers are);
* ``header`` — one byte of the first 4 KiB set to a value drawn from the digits, signs, ``e``,
  separators and NUL, the characters that change a header's numbers, dates and keys.

Outcomes. ``refused``: :class:`brdfscale.MeasurementFileError` naming the file. ``same``: the
field is the undamaged file's (heights, mask, pitch bit for bit) — or, since instrument formats
carry no checksum and a byte of height data hit is a different but valid measurement, the field
is *faithful*: exactly what SurfaceTopography decodes from the damaged file (heights transposed
to rows y, converted to metres, mask, pitch), with finite Σ(μ) at the pixel scale and at a
quarter of the field. The faithful ones are counted in ``same`` and also on their own
(``"faithful"``). ``bad``: any other exception, a field that is neither, non-finite statistics,
or text on stdout/stderr while reading (warnings are recorded by Python, not printed, and
do not count).

Hostile heights (``hostile_heights``). Height maps written as text files (SurfaceTopography's
``AscReader``: ``# Width: …`` headers) and passed through ``brdfscale topography FILE --out
DIR`` in this process, and arrays through :func:`brdfscale.topography.from_array`: a flat
surface (detrended and not), random heights × 1e-310 (denormal), × 1e150 and × 1e300 (huge), a
surface with NaN patches, pitches of 1e-300 m, 1e300 m and a ratio of 1e10, an infinite height.
Expected: the flat surface measured with Σ(μ) = 0 at every scale and the figure written; NaN
patches measured exactly as the same heights with an explicit mask (and so an infinite height
in a file, which SurfaceTopography's reader masks); the others refused — exit 2 with one line
``brdfscale topography: error: …`` (or InvalidInputError from ``from_array``, which refuses an
infinite height: NaN marks unmeasured pixels there).
``same`` is the expected success, ``refused`` the expected refusal; anything else is ``bad``.

The mutations and the verdict on one file (the oracle ``faithful`` included) are
tests/references/topography_mutation.py's, shared with tests/test_topography_robustness.py.

Sizes: quick 3 mutants per byte kind and 7 hostile trials (≈ 10 s); full 250 per byte kind
(1 250 mutated files) and every hostile case through both paths with 4 seeds.
"""

import json
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np

from experiments import _fuzz_common
from tests.references.topography_mutation import (
    BYTE_KINDS,
    DATA,
    FILES,
    mutate,
    read_outcome,
    same_field,
    write_ascii,
)


#: the byte kinds of tests/references/topography_mutation.py, then the hostile heights
KINDS = (*BYTE_KINDS, "hostile_heights")


# -- hostile heights -------------------------------------------------------------------------


#: The hostile cases: name → (heights from a generator, (Δx, Δy) in metres, detrend, expected).
def hostile_cases(rng: np.random.Generator) -> dict:
    n = 24
    rough = rng.standard_normal((n, n)) * 1e-8
    patches = rough.copy()
    for _ in range(3):
        j, k = rng.integers(0, n - 4, 2)
        patches[j : j + int(rng.integers(1, 4)), k : k + int(rng.integers(1, 4))] = np.nan
    infinite = rough.copy()
    infinite[int(rng.integers(n)), int(rng.integers(n))] = np.inf
    return {
        "flat": (np.full((n, n), 3.7e-7), (1e-7, 1e-7), "plane", "measured_flat"),
        "flat_not_detrended": (np.full((n, n), -2e-6), (1e-7, 1e-7), "none", "measured_flat"),
        "denormal": (rough * 1e-302, (1e-7, 1e-7), "plane", "refused"),
        "huge_1e150": (rough * 1e150, (1e-7, 1e-7), "plane", "refused"),
        "huge_1e300": (rough * 1e300, (1e-7, 1e-7), "plane", "refused"),
        "nan_patches": (patches, (1e-7, 1e-7), "plane", "measured_masked"),
        "pitch_1e-300": (rough, (1e-300, 1e-300), "plane", "refused"),
        "pitch_1e300": (rough, (1e300, 1e300), "plane", "refused"),
        "pitch_ratio_1e10": (rough, (1e-7, 1e3), "plane", "refused"),
        # from_array refuses ±inf (NaN marks unmeasured); SurfaceTopography's readers mask it: unmeasured
        "infinite_height": (infinite, (1e-7, 1e-7), "plane", ("refused", "measured_masked")),
    }


def _array_trial(heights, pitch, detrend, expected) -> tuple[str, str]:
    from brdfscale import BrdfscaleError, InvalidInputError, synth, topography

    mode = None if detrend == "none" else detrend
    try:
        with np.errstate(all="ignore"):
            field = topography.from_array(heights, pitch, detrend=mode)
        stats = synth.facet_statistics(field, field.scales(3), bins=9)
    except InvalidInputError as err:
        return ("refused", "") if expected == "refused" else ("bad", f"from_array refused a valid map: {err}")
    except BrdfscaleError as err:
        return "bad", f"{type(err).__name__} instead of InvalidInputError: {err}"
    except Exception as err:  # noqa: BLE001
        return "bad", f"from_array: {type(err).__name__}: {' '.join(str(err).split())[:160]}"
    if expected == "refused":
        return "bad", f"accepted (steepest slope {field.steepest_slope:.3g}, Σ {stats[0].covariance.ravel()})"
    if expected == "measured_flat":
        ok = all(np.all(s.covariance == 0) for s in stats)
        return ("same", "") if ok else ("bad", "a flat surface gave Σ ≠ 0")
    masked = topography.from_array(np.nan_to_num(heights), pitch, mask=~np.isnan(heights), detrend=mode)
    ok = same_field(field, masked) and all(np.all(np.isfinite(s.covariance)) for s in stats)
    return ("same", "") if ok else ("bad", "NaN patches not measured as the explicit mask")


def _command_trial(directory: str, name: str, heights, pitch, detrend, expected) -> tuple[str, str]:
    path = os.path.join(directory, f"{name}.txt")
    out = os.path.join(directory, f"{name}-out")
    shutil.rmtree(out, ignore_errors=True)
    write_ascii(path, heights, *pitch)
    code, stdout, stderr = _fuzz_common.in_process(
        quiet=True, argv=["topography", path, "--detrend", detrend, "--out", out]
    )
    lines = [line for line in stderr.splitlines() if line.strip()]
    if expected == "refused":
        one_line = len(lines) == 1 and lines[0].startswith("brdfscale topography: error:") and path in lines[0]
        if code == 2 and one_line and not os.path.exists(os.path.join(out, "statistics.json")):
            return "refused", ""
        return "bad", f"{name}: exit {code}, stderr {stderr.strip()[:160]!r}"
    if code != 0 or not os.path.isfile(os.path.join(out, "statistics.png")):
        return "bad", f"{name}: exit {code}, stderr {stderr.strip()[:160]!r}"
    with open(os.path.join(out, "statistics.json"), encoding="utf-8") as f:
        doc = json.load(f)
    covs = [np.array(s["covariance"], dtype=float) for s in doc["scales"]]
    if expected == "measured_flat":
        ok = doc["field"]["flat"] and all(np.all(c == 0) for c in covs) and "flat" in stdout
    else:
        ok = all(np.all(np.isfinite(c)) for c in covs) and doc["field"]["unmeasured_pixels"] > 0
    return ("same", "") if ok else ("bad", f"{name}: statistics.json not as expected")


def run(quick: bool, seed: int = 0, directory: str | None = None) -> dict:
    """The family's tallies (module docstring); deterministic for a seed."""
    from brdfscale import topography

    kinds = _fuzz_common.tally(KINDS)
    faithful_counts = {k: 0 for k in BYTE_KINDS}
    bad_examples: list[str] = []
    work = tempfile.mkdtemp(prefix="fuzz-topography-", dir=directory)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            references = {name: topography.read(str(DATA / name), detrend=None) for name in FILES}
        originals = {name: (DATA / name).read_bytes() for name in FILES}
        per_kind = 3 if quick else 250
        for k, kind in enumerate(BYTE_KINDS):
            rng = np.random.default_rng([seed, k])
            for trial in range(per_kind):
                name = FILES[(trial + k) % len(FILES)]
                path = os.path.join(work, f"mutant{Path(name).suffix}")
                with open(path, "wb") as f:
                    f.write(mutate(originals[name], kind, rng))
                verdict, why = read_outcome(path, references[name])
                kinds[kind]["tried"] += 1
                if verdict == "faithful":
                    faithful_counts[kind] += 1
                    verdict = "same"
                kinds[kind][verdict] += 1
                if verdict == "bad" and len(bad_examples) < 20:
                    bad_examples.append(f"{kind} of {name} (seed {seed}, trial {trial}): {why}")
        seeds = [seed] if quick else [seed + s for s in range(4)]
        for s in seeds:
            cases = hostile_cases(np.random.default_rng([seed, 99, s]))
            if quick:
                cases = {c: cases[c] for c in ("flat", "denormal", "huge_1e300", "nan_patches", "pitch_1e-300")}
            for c, (heights, pitch, detrend, expected) in cases.items():
                array, command = expected if isinstance(expected, tuple) else (expected, expected)
                trials = [_array_trial(heights, pitch, detrend, array)]
                if not quick or c in ("flat", "huge_1e300"):
                    trials.append(_command_trial(work, c, heights, pitch, detrend, command))
                for verdict, why in trials:
                    kinds["hostile_heights"]["tried"] += 1
                    kinds["hostile_heights"][verdict] += 1
                    if verdict == "bad" and len(bad_examples) < 20:
                        bad_examples.append(f"hostile_heights {c} (seed {s}): {why}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return {"kinds": kinds, "bad_examples": bad_examples, "faithful": faithful_counts}


if __name__ == "__main__":
    import sys

    sys.exit(_fuzz_common.main(run, __doc__))
