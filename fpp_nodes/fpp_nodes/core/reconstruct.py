"""Fringe images to depth and XYZ: the multi-shot path (phase shifting at every frequency, temporal
unwrapping, rational model) and the single-shot FTP baseline. Pure functions of arrays."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .calibration import Calibration, back_project
from .patterns import CODE_ORDERS, PatternSet
from .phase import (TWO_PI, PhaseError, ftp_code_phase, ftp_wrapped_phase, sin_cos_sums, unwrap_spatial,
                    unwrap_temporal, _atan2_positive)


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


# The composite's confidence is a vote over this window (pixels): on the composite set's validation
# split 9 gave the most coverage within 0.5% silent errors (15 a little less, 5 let more errors through).
VOTE_WINDOW = 9


class CompositeDecoder:
    """The composite pattern's two phases -> depth, for a calibration with a code model.

    Each pixel's carrier order is one of CODE_ORDERS consecutive orders that span the working range
    (depth_range_mm, with equal slack at both ends); the code phase says which: it is the row phase
    plus the absolute carrier phase / CODE_ORDERS, so each candidate order predicts it about 2 pi /
    CODE_ORDERS from the next. Across the candidates the row phase drifts (the projector row a pixel
    sees moves with depth) almost linearly in the carrier phase: fitted so per pixel (within 1e-3 rad
    in the default rig), each pixel's order follows in closed form (code_phase).
    min_separation is how close the codes of two orders of the working range come on this rig (rad,
    over a grid of pixels): the margin every decision has is half of it.

    One pixel's code is noisy; a surface's is not: its absolute phase is smooth, and a wrong order is
    2 pi off. A pixel keeps its order only where it is the order nearest the median phase of the 5 x 5
    pixels around it (taken twice); its confidence is the vote: the share of the pixels in the
    VOTE_WINDOW around it that keep their order so (a check of each pixel's code residual as well
    bought no coverage at equal silent errors on validation data). Depth is NaN where a pixel does
    not, below min_confidence and where the image shows no fringes: the decoder never adopts an order
    a pixel's own code did not give.
    """

    def __init__(self, calibration: Calibration, depth_range_mm: tuple[float, float]):
        if calibration.code_model is None:
            raise PhaseError("the composite decoder needs a calibration made with the composite pattern (a code model)")
        cam = calibration.camera
        u = np.arange(cam.width, dtype=np.float64)[None, :]
        v = np.arange(cam.height, dtype=np.float64)[:, None]
        ends = [np.broadcast_to(calibration.model.phase_at_depth(z, u, v), (cam.height, cam.width)) for z in depth_range_mm]
        span = np.abs(ends[1] - ends[0]) / TWO_PI
        if span.max() > CODE_ORDERS - 1:
            raise PhaseError(f"the working range {depth_range_mm[0]:g}-{depth_range_mm[1]:g} mm spans up to {span.max():.1f} "
                             f"fringe orders; the composite's code tells {CODE_ORDERS} apart")
        lowest = np.minimum(ends[0], ends[1]) - (CODE_ORDERS - span) / 2 * TWO_PI
        # the row phase along the window, a straight line in the carrier phase per pixel (least squares)
        t = np.arange(CODE_ORDERS + 1) - CODE_ORDERS / 2
        rows = [self._row(calibration, lowest + TWO_PI * (k + CODE_ORDERS / 2), u, v) for k in t]
        slope = sum(k * r for k, r in zip(t, rows)) / (np.sum(t * t) * TWO_PI)
        middle = lowest + np.pi * CODE_ORDERS
        intercept = sum(rows) / len(rows) - slope * middle
        self.row_fit_error = max(float(np.abs(intercept + slope * (middle + TWO_PI * k) - r).max()) for k, r in zip(t, rows))
        self.lowest, self.row_intercept = lowest.astype(np.float32), intercept.astype(np.float32)
        self.row_rate = (slope + 1 / CODE_ORDERS).astype(np.float32)  # d(predicted code) / d(carrier phase)
        self.spacing = (TWO_PI * self.row_rate).astype(np.float32)  # the code from one order to the next
        # the candidates inside the working range, with half an order to spare at each end
        self.first = np.floor((CODE_ORDERS - span) / 2 - 0.5).astype(np.float32)
        self.last = np.ceil((CODE_ORDERS + span) / 2 + 0.5).astype(np.float32)
        self.min_separation = self._separation(calibration, ends, u, v)
        self.terms = depth_terms(calibration)

    @staticmethod
    def _row(calibration: Calibration, phase, u, v):
        return calibration.code_row_phase_at_depth(calibration.model.depth(phase, u, v), u, v)

    def _separation(self, calibration: Calibration, ends, u, v, step: int = 8) -> float:
        """How close the codes of two orders in the working range come, over every step-th pixel (rad)."""
        u, v = u[:, ::step], v[::step]
        lo = np.minimum(ends[0], ends[1])[::step, ::step]
        hi = np.maximum(ends[0], ends[1])[::step, ::step]
        codes, inside = [], []
        for k in range(int(np.ceil((hi - lo).max() / TWO_PI)) + 1):
            phase = lo + TWO_PI * k
            codes.append(self._row(calibration, phase, u, v) + phase / CODE_ORDERS)
            inside.append(phase <= hi)
        closest = np.inf
        for a in range(len(codes)):
            for b in range(a + 1, len(codes)):
                d = np.abs(np.mod(codes[a] - codes[b] + np.pi, TWO_PI) - np.pi)
                closest = min(closest, float(np.where(inside[a] & inside[b], d, np.inf).min()))
        return closest

    def code_phase(self, carrier: np.ndarray, code: np.ndarray) -> np.ndarray:
        """Each pixel's absolute carrier phase as its own code tells it.

        With the row phase a + b Phi, the j-th candidate Phi = lowest + 2 pi j predicts the code
        a + (b + 1/K) lowest + j s, s = 2 pi (b + 1/K): j s = q + 2 pi m for q, the code left over, and
        a whole number m of turns (the predictions span about one turn, so m is -1, 0 or 1); of the
        candidates inside the working range the one the code fits best."""
        two_pi = np.float32(TWO_PI)
        lowest = carrier + two_pi * np.ceil((self.lowest - carrier) / two_pi)  # the lowest candidate's phase
        q = code - self.row_intercept - self.row_rate * lowest
        q -= two_pi * np.floor(q / two_pi)
        best_j = best_miss = None
        for turns in (-1, 0, 1):
            turned = q + np.float32(turns) * two_pi
            j = np.rint(turned / self.spacing)
            miss = np.abs(turned - j * self.spacing)
            miss[(j < self.first) | (j > self.last)] = np.inf
            if best_j is None:
                best_j, best_miss = j, miss
            else:
                better = miss < best_miss
                best_j[better], best_miss[better] = j[better], miss[better]
        return lowest + two_pi * best_j

    def __call__(self, out: np.ndarray, min_confidence: float,
                 fringes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """out: (4, H, W) carrier numerator, denominator, code numerator, denominator; fringes: the
        pixels that show fringes (default all). Returns (depth mm, confidence), NaN where unknown."""
        num, den, code_num, code_den = (np.ascontiguousarray(c, np.float32) for c in out)
        two_pi = np.float32(2 * np.pi)
        carrier = cv2.phase(den, num)
        own = self.code_phase(carrier, cv2.phase(code_den, code_num))
        if fringes is None:
            fringes = np.ones(carrier.shape, bool)
        local = np.where(fringes, own, np.float32(0))
        for _ in range(2):  # the order nearest the neighbourhood's median phase
            local = carrier + two_pi * np.rint((cv2.medianBlur(local, 5) - carrier) / two_pi)
        agree = (np.abs(own - local) < np.pi) & fringes
        confidence = cv2.boxFilter(agree.astype(np.float32), -1, (VOTE_WINDOW, VOTE_WINDOW),
                                   borderType=cv2.BORDER_REPLICATE)
        confidence[~fringes] = np.nan
        ca, cb, da, db = self.terms
        depth = (ca + cb * own) / (da + db * own)
        depth[~(agree & (confidence >= min_confidence))] = np.nan
        return depth, confidence


FTP_MIN_CONFIDENCE = 0.5  # the composite by FTP: not tuned (a baseline), half the neighbourhood agrees


def composite_ftp_phases(image: np.ndarray, calibration: Calibration):
    """(carrier phase, code phase, carrier lobe amplitude) of a composite image by FTP, each lobe where
    the calibration puts it at the reference depth (the median phase slope, in cycles per image)."""
    cal = calibration
    u = np.arange(cal.camera.width, dtype=np.float64)[None, :]
    v = np.arange(cal.camera.height, dtype=np.float64)[:, None]
    carrier = cal.model.phase_at_depth(cal.reference_depth_mm, u, v) * np.ones(image.shape)
    code = carrier / CODE_ORDERS + cal.code_row_phase_at_depth(cal.reference_depth_mm, u, v)
    h, w = image.shape
    carrier, amplitude = ftp_wrapped_phase(image, True, carrier=np.median(np.diff(carrier, axis=1)) * w / TWO_PI)
    code, _ = ftp_code_phase(image, centre=(np.median(np.diff(code, axis=1)) * w / TWO_PI,
                                            np.median(np.diff(code, axis=0)) * h / TWO_PI))
    return carrier, code, amplitude


def reconstruct_ftp(image: np.ndarray, calibration: Calibration, limits: QualityLimits = QualityLimits(),
                    decoder: CompositeDecoder | None = None) -> Reconstruction:
    """Single-shot baseline: Takeda's FTP wrapped phase, then the same rational model.

    With the composite (a calibration with a code model) the code grating's own lobe tells each
    pixel's fringe order through decoder (a CompositeDecoder for this calibration and the working
    range: made once by the caller, it is costly to make); both lobes are taken where the calibration
    puts them at the reference depth. With the paper's image there is no order to tell: the phase is
    unwrapped spatially, and the global multiple of 2 pi is chosen to put the median pixel at the
    calibration's reference depth (the background), as a reference-plane FTP set-up does.
    """
    cal = calibration
    image = np.asarray(image)
    if image.shape != (cal.camera.height, cal.camera.width):
        raise PhaseError(f"expected one {cal.camera.width}x{cal.camera.height} image, got shape {image.shape}")
    u = np.arange(cal.camera.width, dtype=np.float64)[None, :]
    v = np.arange(cal.camera.height, dtype=np.float64)[:, None]
    if cal.code_model is not None:
        if decoder is None:
            raise PhaseError("the composite's FTP needs a CompositeDecoder for the working range its code spans")
        carrier, code, amplitude = composite_ftp_phases(image, cal)
        fringes = amplitude >= limits.min_modulation * full_scale(image.dtype)
        out = np.stack([np.sin(carrier), np.cos(carrier), np.sin(code), np.cos(code)])
        depth, _ = decoder(out, FTP_MIN_CONFIDENCE, fringes)
        depth, valid = trusted_depth(depth, np.isfinite(depth), limits.max_depth_step_mm)
        phase = cal.model.phase_at_depth(depth, u, v)
        return Reconstruction(depth, back_project(depth, cal.camera), valid, amplitude.astype(np.float32),
                              phase.astype(np.float32))
    vertical = cal.patterns.orientation == "vertical"
    reference = cal.model.phase_at_depth(cal.reference_depth_mm, u, v) * np.ones(image.shape)
    wrapped, amplitude = ftp_wrapped_phase(image, vertical)
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
