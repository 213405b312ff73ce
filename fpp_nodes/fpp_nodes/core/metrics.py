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
        return {"rmse_mm": self.rmse_mm, "mre": self.mre, "coverage": self.coverage,
                "order_errors": self.order_errors, "pixels": self.pixels}


def compared_pixels(pred: np.ndarray, truth: np.ndarray, truth_valid: np.ndarray | None = None) -> np.ndarray:
    mask = np.isfinite(pred) & np.isfinite(truth)
    return mask if truth_valid is None else mask & truth_valid


def rmse(pred, truth, mask) -> float:
    """Root mean squared error over mask, in the inputs' units."""
    diff = (np.asarray(pred, np.float64) - truth)[mask]
    return float(np.sqrt(np.mean(diff * diff))) if diff.size else float("nan")


def mre(pred, truth, mask) -> float:
    """Mean relative error |pred - truth| / |truth| over mask."""
    t = np.asarray(truth, np.float64)[mask]
    return float(np.mean(np.abs(np.asarray(pred, np.float64)[mask] - t) / np.abs(t))) if t.size else float("nan")


def depth_errors(pred, truth, truth_valid=None, fringe_depth_mm: np.ndarray | float | None = None) -> DepthErrors:
    """All metrics at once. fringe_depth_mm is the depth one fringe period of the highest frequency
    spans (per pixel or scalar); an error over half of it is a wrong fringe order."""
    mask = compared_pixels(pred, truth, truth_valid)
    reference = np.isfinite(truth) if truth_valid is None else truth_valid & np.isfinite(truth)
    orders = 0
    if fringe_depth_mm is not None:
        half = 0.5 * np.broadcast_to(fringe_depth_mm, mask.shape)
        orders = int(np.count_nonzero(np.abs(np.where(mask, pred - truth, 0.0)) > half))
    return DepthErrors(rmse(pred, truth, mask), mre(pred, truth, mask),
                       float(mask.sum() / max(reference.sum(), 1)), orders, int(mask.sum()))


def noise_limited_depth_std(modulation, depth_per_radian, steps: int, noise_sigma: float) -> np.ndarray:
    """Depth standard deviation that camera noise alone causes, per pixel.

    With independent noise of standard deviation sigma on each of N images, the least-squares phase
    has standard deviation sigma_phi = sqrt(2 / N) sigma / B (B the fringe modulation), and the depth
    moves by |dz/dphi| sigma_phi. sigma should include the camera's rounding (1/12 count^2 variance).
    """
    return np.abs(depth_per_radian) * np.sqrt(2.0 / steps) * noise_sigma / np.asarray(modulation, np.float64)
