"""Accuracy metrics, all over the pixels valid in both the prediction and the ground truth.

RMSE (mm) = sqrt(mean((z_pred - z_true)^2))
MRE       = mean(|z_pred - z_true| / |z_true|)      (dimensionless, relative to the true depth)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class DepthErrors:
    rmse_mm: float
    mre: float
    coverage: float  # fraction of ground-truth-valid pixels the prediction covers
    order_errors: int  # covered pixels off by more than half a fringe period in depth (if given)
    pixels: int

    def as_row(self) -> dict:
        return {
            "rmse_mm": self.rmse_mm,
            "mre": self.mre,
            "coverage": self.coverage,
            "order_errors": self.order_errors,
            "pixels": self.pixels,
        }


class ErrorTotals:
    """Errors summed over the pixels valid in both prediction and reference, over one image or a whole
    data set: RMSE, MRE, coverage of the reference's valid pixels, and how many compared pixels are
    off by more than a bound (a wrong fringe order; a silent error)."""

    def __init__(self):
        self.squared = self.relative = 0.0
        self.compared = self.reference = self.over = 0

    def add(self, pred, reference, bound=None) -> ErrorTotals:
        """bound: a scalar or a per-pixel array in the inputs' units."""
        pred, reference = np.asarray(pred), np.asarray(reference)
        ok = np.isfinite(pred) & np.isfinite(reference)
        d = pred[ok].astype(np.float64) - reference[ok]
        self.squared += float(d @ d)
        self.relative += float(np.sum(np.abs(d) / np.abs(reference[ok])))
        self.compared += d.size
        self.reference += int(np.count_nonzero(np.isfinite(reference)))
        if bound is not None:
            self.over += int(np.count_nonzero(np.abs(d) > np.broadcast_to(bound, ok.shape)[ok]))
        return self

    def merge(self, other: ErrorTotals) -> ErrorTotals:
        """Pool other's sums into these: the errors over both sets of pixels, without adding them again."""
        for name, value in vars(other).items():
            setattr(self, name, getattr(self, name) + value)
        return self

    @property
    def rmse(self) -> float:
        return float(np.sqrt(self.squared / self.compared)) if self.compared else float("nan")

    @property
    def mre(self) -> float:
        return self.relative / self.compared if self.compared else float("nan")

    @property
    def coverage(self) -> float:
        return self.compared / max(self.reference, 1)

    @property
    def share_over(self) -> float:
        return self.over / max(self.compared, 1)


def depth_errors(pred, truth, truth_valid=None, fringe_depth_mm: np.ndarray | float | None = None) -> DepthErrors:
    """One image's errors. fringe_depth_mm is the depth one fringe period of the highest frequency
    spans (per pixel or scalar); an error over half of it is a wrong fringe order."""
    reference = truth if truth_valid is None else np.where(truth_valid, truth, np.nan)
    t = ErrorTotals().add(pred, reference, None if fringe_depth_mm is None else 0.5 * np.asarray(fringe_depth_mm))
    return DepthErrors(t.rmse, t.mre, t.coverage, t.over, t.compared)


def noise_limited_depth_std(modulation, depth_per_radian, steps: int, noise_sigma: float) -> np.ndarray:
    """Depth standard deviation that camera noise alone causes, per pixel.

    With independent noise of standard deviation sigma on each of N images, the least-squares phase
    has standard deviation sigma_phi = sqrt(2 / N) sigma / B (B the fringe modulation), and the depth
    moves by |dz/dphi| sigma_phi. sigma should include the camera's rounding (1/12 count^2 variance).
    """
    return np.abs(depth_per_radian) * np.sqrt(2.0 / steps) * noise_sigma / np.asarray(modulation, np.float64)
