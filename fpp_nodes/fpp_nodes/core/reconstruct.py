"""Fringe images to depth and XYZ: the multi-shot path (phase shifting at every frequency, temporal
unwrapping, rational model) and the single-shot FTP baseline. Pure functions of arrays."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .calibration import Calibration, back_project
from .patterns import PatternSet
from .phase import (TWO_PI, PhaseError, ftp_wrapped_phase, sin_cos_sums, unwrap_spatial, unwrap_temporal,
                    _atan2_positive)


@dataclass
class Reconstruction:
    depth_mm: np.ndarray  # (H, W) float32, NaN where invalid
    xyz_mm: np.ndarray  # (H, W, 3) float32, optical frame, NaN where invalid
    valid: np.ndarray  # (H, W) bool
    quality: np.ndarray  # (H, W) float32: fringe modulation B (PSP) or lobe amplitude (FTP), image units
    phase: np.ndarray  # (H, W) unwrapped phase of the highest frequency


@dataclass(frozen=True)
class QualityLimits:
    """Which pixels to trust. min_modulation is a fraction of the camera's full scale; a pixel whose
    depth differs from a 4-neighbour's by more than max_depth_step_mm mixes two surfaces (a flying
    pixel at an edge) and is dropped with that neighbour."""

    min_modulation: float = 0.05
    max_order_residual: float = np.pi / 2
    max_depth_step_mm: float = 2.0

    def __post_init__(self):
        if not 0 <= self.min_modulation < 0.5:
            raise ValueError(f"min_modulation must be in [0, 0.5), got {self.min_modulation}")
        if not 0 < self.max_order_residual < np.pi:
            raise ValueError(f"max_order_residual must be in (0, pi), got {self.max_order_residual}")
        if not self.max_depth_step_mm > 0:
            raise ValueError(f"max_depth_step_mm must be > 0, got {self.max_depth_step_mm}")


def full_scale(dtype) -> float:
    """The brightest value a camera image of this dtype holds (1.0 for float images)."""
    return float(np.iinfo(dtype).max) if np.issubdtype(dtype, np.integer) else 1.0


def drop_flying_pixels(depth: np.ndarray, max_step: float) -> np.ndarray:
    """Mask of pixels whose depth is within max_step of all finite 4-neighbours."""
    ok = np.isfinite(depth)
    jump_x = np.abs(depth[:, 1:] - depth[:, :-1]) > max_step
    jump_y = np.abs(depth[1:, :] - depth[:-1, :]) > max_step
    ok[:, 1:] &= ~jump_x
    ok[:, :-1] &= ~jump_x
    ok[1:, :] &= ~jump_y
    ok[:-1, :] &= ~jump_y
    return ok


def multi_frequency_phase(images: np.ndarray, patterns: PatternSet, limits: QualityLimits = QualityLimits()):
    """Unwrapped phase of the highest frequency from a sequence (F*N phase-shift images in projection
    order, then the single-shot composite when the set has one), the mask of pixels to trust (well
    modulated, unsaturated, consistent fringe order) and the modulation of the highest frequency."""
    n = patterns.steps
    if images.ndim != 3 or images.shape[0] != patterns.count:
        raise PhaseError(f"expected {patterns.count} images ({_described(patterns)}), got an array shaped {images.shape}")
    wrapped = []
    for i in range(len(patterns.frequencies)):
        s, c = sin_cos_sums(images[i * n:(i + 1) * n])
        if i == len(patterns.frequencies) - 1:
            modulation = cv2.magnitude(s, c)
            modulation *= 2.0 / n
        wrapped.append(_atan2_positive(np.negative(s, out=s), c))
    phase, valid = unwrap_temporal(wrapped, patterns.frequencies, limits.max_order_residual)
    scale = full_scale(images.dtype)
    valid &= modulation >= limits.min_modulation * scale
    if np.issubdtype(images.dtype, np.integer):
        top = images[patterns.top_frequency_frames]
        brightest = top[0]
        for img in top[1:]:
            brightest = cv2.max(brightest, img)
        valid &= brightest < scale  # saturated pixels clip the sinusoid
    return phase.astype(np.float32, copy=False), valid, modulation.astype(np.float32, copy=False)


def _described(patterns: PatternSet) -> str:
    composite = " + the single-shot composite" if patterns.single_shot == "composite" else ""
    return f"{len(patterns.frequencies)} frequencies x {patterns.steps} steps{composite}"


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def trusted_depth(depth: np.ndarray, valid: np.ndarray, max_step: float) -> tuple[np.ndarray, np.ndarray]:
    """Set depth to NaN (in place) where it is not to be trusted: invalid pixels, their 4-neighbours
    (defocus carries fringes from across a shadow edge into them), and flying pixels."""
    valid = cv2.erode(valid.astype(np.uint8), _CROSS).view(bool)
    depth[~valid] = np.nan
    valid = drop_flying_pixels(depth, max_step)
    depth[~valid] = np.nan
    return depth, valid


def depth_terms(calibration: Calibration) -> list[np.ndarray]:
    """The rational model's per-pixel terms (ca, cb, da, db), float32 at the camera's size, so that
    depth = (ca + cb phi) / (da + db phi): computed once per calibration, not per image."""
    cam = calibration.camera
    u = np.arange(cam.width, dtype=np.float64)[None, :]
    v = np.arange(cam.height, dtype=np.float64)[:, None]
    return [np.ascontiguousarray(np.broadcast_to(t, (cam.height, cam.width)), np.float32)
            for t in calibration.model.linear_in_phase(u, v)]


class PspReconstructor:
    """The multi-shot path for one calibration; per-pixel model terms are computed once, here.

    Call with the (F*N, H, W) stack in projection order (all steps of frequency 1, then the next).
    """

    def __init__(self, calibration: Calibration, limits: QualityLimits = QualityLimits()):
        self.calibration = calibration
        self.limits = limits
        self._ca, self._cb, self._da, self._db = depth_terms(calibration)

    def check(self, images: np.ndarray) -> None:
        cal = self.calibration
        expected = (cal.patterns.count, cal.camera.height, cal.camera.width)
        if images.shape != expected:
            raise PhaseError(f"expected {expected[0]} images of {expected[2]}x{expected[1]} "
                             f"({_described(cal.patterns)}), got an array shaped {images.shape}")

    def __call__(self, images: np.ndarray) -> Reconstruction:
        images = np.asarray(images)
        self.check(images)
        phase, valid, modulation = multi_frequency_phase(images, self.calibration.patterns, self.limits)
        return self._to_depth(phase, valid, modulation)

    def _to_depth(self, phase, valid, quality) -> Reconstruction:
        num = cv2.multiply(self._cb, phase)
        num += self._ca
        den = cv2.multiply(self._db, phase)
        den += self._da
        depth, valid = trusted_depth(cv2.divide(num, den), valid, self.limits.max_depth_step_mm)
        return Reconstruction(depth, back_project(depth, self.calibration.camera), valid, quality, phase)


def reconstruct_ftp(image: np.ndarray, calibration: Calibration, limits: QualityLimits = QualityLimits()) -> Reconstruction:
    """Single-shot baseline: FTP wrapped phase, spatial unwrapping, then the same rational model.

    One image carries no absolute fringe order, so the global multiple of 2 pi is chosen to put the
    median pixel at the calibration's reference depth (the background), as a reference-plane FTP
    set-up does.
    """
    cal = calibration
    image = np.asarray(image)
    if image.shape != (cal.camera.height, cal.camera.width):
        raise PhaseError(f"expected one {cal.camera.width}x{cal.camera.height} image, got shape {image.shape}")
    vertical = cal.patterns.orientation == "vertical"
    wrapped, amplitude = ftp_wrapped_phase(image, vertical)
    u = np.arange(cal.camera.width, dtype=np.float64)[None, :]
    v = np.arange(cal.camera.height, dtype=np.float64)[:, None]
    reference = cal.model.phase_at_depth(cal.reference_depth_mm, u, v) * np.ones(image.shape)
    # The lobe's phase grows along +x; flip it where the projector phase falls along +x.
    along = reference[:, -1] - reference[:, 0] if vertical else reference[-1, :] - reference[0, :]
    if np.median(along) < 0:
        wrapped = np.mod(-wrapped, TWO_PI)
    phase = unwrap_spatial(wrapped)
    phase += TWO_PI * np.rint(np.median(reference - phase) / TWO_PI)
    valid = amplitude >= limits.min_modulation * full_scale(image.dtype)
    depth, valid = trusted_depth(cal.model.depth(phase, u, v).astype(np.float32), valid, limits.max_depth_step_mm)
    return Reconstruction(depth, back_project(depth, cal.camera), valid, amplitude.astype(np.float32),
                          phase.astype(np.float32))
