"""Streaming slope histograms on a regular grid of nodes (cloud in cell)."""

import numpy as np

from .. import stats
from .._errors import InvalidInputError


class SlopeHistogram:
    """Accumulates weighted slope samples onto a ``bins × bins`` grid of nodes, chunk by chunk.

    The nodes span ``[−extent, extent]`` on both axes (rows m_y, columns m_x: the layout of
    :class:`brdfscale.stats.Tabulated`). Each sample is shared among the four surrounding
    nodes with bilinear weights (cloud in cell), the scheme of
    :meth:`brdfscale.stats.Tabulated.from_samples`, so the bilinear interpolant of
    ``counts / h²`` integrates to the total weight of the samples inside the grid. Unlike
    ``from_samples`` it takes samples in chunks (constant memory for 4096² fields) and keeps
    the weight that fell outside, so a lobe can be reported as a fraction of *all* samples.
    """

    def __init__(self, extent: float, bins: int):
        if not (np.isfinite(extent) and extent > 0):
            raise InvalidInputError(f"extent must be a positive slope half-width; got {extent!r}.")
        if isinstance(bins, bool) or not isinstance(bins, (int, np.integer)) or bins < 2:
            raise InvalidInputError(f"bins must be an integer ≥ 2; got {bins!r}.")
        self.extent = float(extent)
        self.bins = int(bins)
        self.spacing = 2 * self.extent / (self.bins - 1)
        self.counts = np.zeros(self.bins * self.bins)
        self.total_weight = 0.0

    def add(self, mx: np.ndarray, my: np.ndarray, weights: np.ndarray | None = None) -> None:
        """Add samples with slope components ``mx``, ``my`` (equal shapes) and optional weights."""
        gx = (np.ravel(mx) + self.extent) / self.spacing
        gy = (np.ravel(my) + self.extent) / self.spacing
        w = np.ones_like(gx) if weights is None else np.ravel(weights).astype(float)
        self.total_weight += float(np.sum(w))
        last = self.bins - 1
        inside = (gx >= 0) & (gx <= last) & (gy >= 0) & (gy <= last)
        gx, gy, w = gx[inside], gy[inside], w[inside]
        ix = np.minimum(gx.astype(np.int64), last - 1)
        iy = np.minimum(gy.astype(np.int64), last - 1)
        fx, fy = gx - ix, gy - iy
        base = iy * self.bins + ix
        size = self.bins * self.bins
        for shift, weight in ((0, (1 - fx) * (1 - fy)), (1, fx * (1 - fy)),
                              (self.bins, (1 - fx) * fy), (self.bins + 1, fx * fy)):
            self.counts += np.bincount(base + shift, weights=w * weight, minlength=size)

    def node_counts(self) -> np.ndarray:
        """The accumulated weights per node, shape (bins, bins)."""
        return self.counts.reshape(self.bins, self.bins)

    def density(self) -> np.ndarray:
        """Node values of the density as a fraction of *all* the weight added (per unit slope area)."""
        if self.total_weight <= 0:
            raise InvalidInputError("no samples (or only zero weights) were added to the histogram.")
        return self.node_counts() / (self.total_weight * self.spacing**2)

    def tabulated(self) -> stats.Tabulated:
        """The histogram as a normalised :class:`brdfscale.stats.Tabulated` density."""
        if not np.any(self.counts > 0):
            raise InvalidInputError(f"no sample fell inside the grid of half-width {self.extent}.")
        return stats.Tabulated(self.node_counts(), extent=self.extent)
