"""Streaming slope histograms on a regular grid of nodes (cloud in cell)."""

import math

import numpy as np

from .._errors import InvalidInputError
from .._show import Shown


MAX_HISTOGRAM_BYTES = 2**31
"""The largest ``bins × bins`` float64 count grid a :class:`SlopeHistogram` allocates (2 GiB)."""


class SlopeHistogram(Shown):
    """Accumulates weighted slope samples onto a ``bins × bins`` grid of nodes, chunk by chunk.

    The nodes span ``[−extent, extent]`` on both axes (rows m_y, columns m_x: the layout of
    :class:`brdfscale.stats.Tabulated`). Each sample is shared among the four surrounding
    nodes with bilinear weights (cloud in cell), so the sum of tent functions on the nodes
    with heights ``counts / h²`` — the meaning of a :class:`~brdfscale.stats.Tabulated` table:
    bilinear between nodes, falling linearly to zero over one spacing beyond the outermost —
    integrates to the total weight of the samples inside the grid and has their mean, exactly.
    It takes samples in chunks (constant memory for 4096² fields; four ``np.bincount`` sums
    per chunk) and counts the samples that fell outside, so a lobe can be reported per
    sample, not renormalised over the grid. :meth:`Tabulated.from_histogram` turns it into a
    normalised density and :meth:`Tabulated.from_samples` is the one-shot use of both.
    """

    def __init__(self, extent: float, bins: int):
        if not (np.isfinite(extent) and extent > 0):
            raise InvalidInputError(f"extent must be a positive slope half-width; got {extent!r}.")
        if isinstance(bins, bool) or not isinstance(bins, (int, np.integer)) or bins < 2:
            raise InvalidInputError(f"bins must be an integer ≥ 2; got {bins!r}.")
        if 8 * int(bins) ** 2 > MAX_HISTOGRAM_BYTES:
            raise InvalidInputError(
                f"bins = {bins} needs {8 * int(bins) ** 2 / 2**30:.3g} GiB of counts, more than MAX_HISTOGRAM_BYTES "
                f"({MAX_HISTOGRAM_BYTES / 2**30:g} GiB); use fewer bins (at most "
                f"{math.isqrt(MAX_HISTOGRAM_BYTES // 8)})."
            )
        self.extent = float(extent)
        self.bins = int(bins)
        self.spacing = 2 * self.extent / (self.bins - 1)
        self.counts = np.zeros(self.bins * self.bins)
        self.samples = 0
        self._signed = False  # whether any negative weight was added

    def _show_items(self):
        return [
            ("extent", self.extent),
            ("bins", self.bins),
            ("samples", self.samples),
            ("inside", float(self.counts.sum())),
        ]

    def add(self, mx: np.ndarray, my: np.ndarray, weights: np.ndarray | None = None) -> None:
        """Add samples with slope components ``mx``, ``my`` (equal shapes) and optional weights."""
        scale, last = 1 / self.spacing, self.bins - 1
        gx = np.ravel(mx) * scale + self.extent * scale
        gy = np.ravel(my) * scale + self.extent * scale
        w = None if weights is None else np.ravel(weights).astype(float)
        if w is not None and w.size and w.min() < 0:
            self._signed = True
        self.samples += gx.size
        if min(gx.min(initial=0), gy.min(initial=0)) < 0 or max(gx.max(initial=0), gy.max(initial=0)) > last:
            inside = (gx >= 0) & (gx <= last) & (gy >= 0) & (gy <= last)
            gx, gy = gx[inside], gy[inside]
            w = None if w is None else w[inside]
        ix = np.minimum(gx.astype(np.int64), last - 1)
        iy = np.minimum(gy.astype(np.int64), last - 1)
        fx, fy = gx - ix, gy - iy
        base = iy * self.bins + ix
        # Bilinear shares from four sums per node: Σw, Σw fx, Σw fy, Σw fx fy.
        size = self.bins * self.bins
        fxy = fx * fy
        if w is not None:
            fx, fy, fxy = fx * w, fy * w, fxy * w
        s1 = np.bincount(base, weights=w, minlength=size).reshape(self.bins, self.bins)
        sx = np.bincount(base, weights=fx, minlength=size).reshape(self.bins, self.bins)
        sy = np.bincount(base, weights=fy, minlength=size).reshape(self.bins, self.bins)
        sxy = np.bincount(base, weights=fxy, minlength=size).reshape(self.bins, self.bins)
        counts = self.counts.reshape(self.bins, self.bins)
        counts += s1 - sx - sy + sxy
        counts[:, 1:] += (sx - sxy)[:, :-1]
        counts[1:, :] += (sy - sxy)[:-1, :]
        counts[1:, 1:] += sxy[:-1, :-1]

    def node_counts(self) -> np.ndarray:
        """The accumulated weights per node, shape (bins, bins).

        With non-negative weights the counts are a non-negative density, but the four-sum form
        of the bilinear shares (``Σw − Σw fx − Σw fy + Σw fx fy``) can leave a node that received
        only shares of ≈ 0 at −1e-15 of a count by round-off: such entries (above −1e-12 of the
        largest count) are returned as 0 (tests/test_topography.py's property test found one on
        a 4 × 4 field). Signed weights (a signed deposit, e.g. of a regularised evolution) are
        returned as accumulated.
        """
        counts = self.counts.reshape(self.bins, self.bins)
        if not self._signed and counts.size and counts.min() < 0:
            floor = -1e-12 * max(float(np.abs(counts).max()), 1e-300)
            counts = np.where((counts < 0) & (counts >= floor), 0.0, counts)
        return counts

    def density(self) -> np.ndarray:
        """Node values of the density per sample added, inside the grid or not (per unit slope area).

        Unweighted, its tent sum (the meaning of :class:`~brdfscale.stats.Tabulated`)
        integrates to the fraction of samples inside the grid; weighted, to the mean weight
        carried inside.
        """
        if self.samples == 0:
            raise InvalidInputError("no samples were added to the histogram.")
        return self.node_counts() / (self.samples * self.spacing**2)
