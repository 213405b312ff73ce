"""Fringe images to depth and XYZ: the multi-shot path (phase shifting at every frequency, temporal
unwrapping, rational model) and the single-shot FTP baseline. Pure functions of arrays."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from . import fused
from .calibration import Calibration, back_project
from .patterns import COMPOSITE_CODES, PatternSet
from .phase import (
    TWO_PI,
    PhaseError,
    blur_variance,
    ftp_code_phases,
    ftp_wrapped_phase,
    pooled_phase_noise,
    residual_bases,
    step_weights,
    unwrap_spatial,
    wrap_phase,
)


@dataclass
class Reconstruction:
    depth_mm: np.ndarray  # (H, W) float32, NaN where invalid
    xyz_mm: np.ndarray  # (H, W, 3) float32, optical frame, NaN where invalid
    valid: np.ndarray  # (H, W) bool
    quality: np.ndarray  # (H, W) float32: PSP the expected depth noise (mm, NaN where invalid); FTP the lobe amplitude
    phase: np.ndarray  # (H, W) unwrapped phase of the highest frequency
    modulation: np.ndarray | None = None  # (H, W) float32: PSP the fringe modulation B, image units
    blur_px: float | None = None  # PSP: the blur the sequence's fringes show (phase.blur_variance), its sqrt


WRAP_SIGMAS = 5.0  # how far, in its noise, the lowest frequency's phase must be from its wrap


@dataclass(frozen=True)
class QualityLimits:
    """Which pixels to trust. The multi-shot path keeps a pixel whose expected depth noise (its phase
    noise through the calibration's dz/dphi) is at most max_depth_noise_mm, whose fringe order agrees
    at every frequency within max_order_residual (rad) and whose top-frequency images are unsaturated.
    The single-shot FTP baseline keeps a pixel whose lobe amplitude is at least min_modulation of full
    scale. A pixel whose depth differs from a 4-neighbour's by more than max_depth_step_mm mixes two
    surfaces (a flying pixel at an edge) and is dropped with that neighbour. Where the albedo changes
    across the fringes, defocus moves the phase towards the brighter side: a pixel whose depth that
    may move by more than max_depth_bias_mm (phase.defocus_phase_bias, with the blur the frame's own
    fringes show) is dropped."""

    max_depth_noise_mm: float = 0.2  # 1 mm is 5 sigma: no pixel off by 1 mm from noise (scripts/quality_cut.py)
    max_order_residual: float = np.pi / 2
    max_depth_step_mm: float = 2.0
    max_depth_bias_mm: float = 0.5  # on validation: no cost in focus, 21% -> 0.06% off by 1 mm on stripes at 1 px
    min_modulation: float = 0.05

    def __post_init__(self):
        if not self.max_depth_noise_mm > 0:
            raise ValueError(f"max_depth_noise_mm must be > 0, got {self.max_depth_noise_mm}")
        if not 0 <= self.min_modulation < 0.5:
            raise ValueError(f"min_modulation must be in [0, 0.5), got {self.min_modulation}")
        if not 0 < self.max_order_residual < np.pi:
            raise ValueError(f"max_order_residual must be in (0, pi), got {self.max_order_residual}")
        if not self.max_depth_step_mm > 0:
            raise ValueError(f"max_depth_step_mm must be > 0, got {self.max_depth_step_mm}")
        if not self.max_depth_bias_mm > 0:
            raise ValueError(f"max_depth_bias_mm must be > 0, got {self.max_depth_bias_mm}")


def drop_flying_pixels(depth: np.ndarray, max_step: float) -> np.ndarray:
    """Mask of the finite pixels whose depth is within max_step of all finite 4-neighbours (one
    compiled pass, fused.steady_pixels)."""
    return fused.steady_pixels(np.asarray(depth, np.float32), max_step)


def multi_frequency_phase(
    images: np.ndarray, patterns: PatternSet, limits: QualityLimits = QualityLimits(), rows: slice = slice(None)
):
    """From a sequence (F*N phase-shift images in projection order, then the single-shot composite when
    the set has one): the unwrapped phase of the highest frequency (phase.unwrap_temporal of each
    frequency's phase.wrapped_phase), the mask of pixels whose fringe order is consistent and whose
    top-frequency images are below full scale (a clipped sinusoid moves the phase), that frequency's
    modulation B, its phase noise (rad, phase.phase_noise) and the next lower frequency's B (what
    phase.blur_variance and phase.defocus_phase_bias read): in one compiled pass, fused.sequence_phase.
    Of these rows only, where rows is given (phase noise pools neighbours: it is exact a few rows in)."""
    n = patterns.steps
    if images.ndim != 3 or images.shape[0] != patterns.count:
        raise PhaseError(
            f"expected {patterns.count} images ({_described(patterns)}), got an array shaped {images.shape}"
        )
    if not np.issubdtype(images.dtype, np.integer) and not np.issubdtype(images.dtype, np.floating):
        raise PhaseError(f"images must be real numbers, got {images.dtype}")
    integer = np.issubdtype(images.dtype, np.integer)
    frequencies = np.asarray(patterns.frequencies, np.float64)
    phase, modulation, valid, power, coarser = fused.sequence_phase(
        np.ascontiguousarray(images),
        *rows.indices(images.shape[1])[:2],
        *step_weights(n),
        frequencies[1:] / frequencies[:-1],
        *residual_bases(n),
        np.float32(limits.max_order_residual / TWO_PI),
        np.float32(full_scale(images.dtype) if integer else np.inf),  # float images: no saturation known
    )
    noise = pooled_phase_noise(power, modulation, n, integer)
    # Every frequency's phase is the same at the projector's first and last columns: where noise could
    # carry the lowest one across its wrap, the order would be a whole turn of it off (a camera that
    # sees the projector's side edges). The top phase's noise bounds the lowest's (blur cuts fine
    # fringes' contrast most).
    turn = np.float32(TWO_PI * frequencies[-1] / frequencies[0])
    valid &= np.minimum(phase, turn - phase) > np.float32(WRAP_SIGMAS * turn / TWO_PI) * noise
    return phase, valid, modulation, noise, coarser


def full_scale(dtype) -> float:
    """The brightest value a camera image of this dtype holds (1.0 for float images)."""
    return float(np.iinfo(dtype).max) if np.issubdtype(dtype, np.integer) else 1.0


def _described(patterns: PatternSet) -> str:
    composite = " + the single-shot composite" if patterns.single_shot == "composite" else ""
    return f"{len(patterns.frequencies)} frequencies x {patterns.steps} steps{composite}"


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def trusted_depth(depth: np.ndarray, valid: np.ndarray, max_step: float) -> tuple[np.ndarray, np.ndarray]:
    """Set depth to NaN (in place) where it is not to be trusted: invalid pixels, their 4-neighbours
    (defocus carries fringes from across a shadow edge into them), and flying pixels."""
    valid = cv2.erode(valid.astype(np.uint8), _CROSS).view(bool)
    np.copyto(depth, np.nan, where=~valid)
    valid = drop_flying_pixels(depth, max_step)
    np.copyto(depth, np.nan, where=~valid)
    return depth, valid


def depth_terms(calibration: Calibration) -> list[np.ndarray]:
    """The rational model's per-pixel terms (ca, cb, da, db), float32 at the camera's size, so that
    depth = (ca + cb phi) / (da + db phi): computed once per calibration, not per image."""
    cam = calibration.camera
    u, v = cam.ideal_pixels()
    return [
        np.ascontiguousarray(np.broadcast_to(t, cam.shape), np.float32) for t in calibration.model.linear_in_phase(u, v)
    ]


class PspReconstructor:
    """The multi-shot path for one calibration; per-pixel model terms are computed once, here.

    Call with the (F*N, H, W) stack in projection order (all steps of frequency 1, then the next).
    The work is per pixel but for small neighbourhoods, so `threads` bands of rows run at once, each
    with BAND_HALO rows of its neighbours: the result is the one-piece result to float32 rounding.
    The per-pixel work is two compiled passes (fused.py) that release the interpreter lock.
    """

    def __init__(self, calibration: Calibration, limits: QualityLimits = QualityLimits(), threads: int = 2):
        if calibration.patterns.steps < 4:
            raise PhaseError(
                f"the multi-shot path estimates each pixel's noise from the N-step fit: it needs N >= 4 "
                f"phase-shift steps, the calibration's pattern set has {calibration.patterns.steps}"
            )
        self.calibration = calibration
        self.limits = limits
        self._terms = np.stack(depth_terms(calibration))
        ca, cb, da, db = self._terms
        self._slope = np.abs(cb * da - ca * db)  # |dz/dphi| (da + db phi)^2
        self._rays = [np.ascontiguousarray(r, np.float32) for r in calibration.camera.rays()]
        height = calibration.camera.height
        edges = np.linspace(0, height, max(1, min(threads, height // (4 * BAND_HALO))) + 1).astype(int)
        self._bands = list(zip(edges[:-1], edges[1:]))
        self._pool = ThreadPoolExecutor(len(self._bands)) if len(self._bands) > 1 else None

    def check(self, images: np.ndarray) -> None:
        cal = self.calibration
        expected = (cal.patterns.count, cal.camera.height, cal.camera.width)
        if images.shape != expected:
            raise PhaseError(
                f"expected {expected[0]} images of {expected[2]}x{expected[1]} "
                f"({_described(cal.patterns)}), got an array shaped {images.shape}"
            )

    def __call__(self, images: np.ndarray) -> Reconstruction:
        images = np.ascontiguousarray(images)
        self.check(images)
        images = self.calibration.camera.full_range(images)
        shape = images.shape[1:]
        out = Reconstruction(
            *(np.empty(shape, np.float32), np.empty((*shape, 3), np.float32), np.empty(shape, bool)),
            *(np.empty(shape, np.float32) for _ in range(3)),
        )
        # each band writes its rows of the outputs; the blur is the whole frame's, between the two passes
        coarser, trusted = np.empty(shape, np.float32), np.empty(shape, bool)
        bands = self._map(lambda rows: self._phase_band(images, *rows, out, coarser, trusted), self._bands)
        blur = blur_variance(out.phase, out.modulation, coarser, self.calibration.patterns.top_ratio, trusted)
        self._map(lambda band: self._depth_band(*band, blur, out), bands)
        out.blur_px = float(np.sqrt(blur))
        return out

    def _map(self, work, items) -> list:
        return [work(i) for i in items] if self._pool is None else list(self._pool.map(work, items))

    def _phase_band(self, images: np.ndarray, first: int, last: int, out: Reconstruction, coarser, trusted):
        """The first pass over rows first to last, from those rows and BAND_HALO more on each side: their
        phase and modulation into out, the lower frequency's modulation and the trusted pixels into
        coarser and trusted; what the second pass needs of the band, halo included."""
        lo, hi = max(0, first - BAND_HALO), min(images.shape[1], last + BAND_HALO)
        band = multi_frequency_phase(images, self.calibration.patterns, self.limits, slice(lo, hi))
        own = slice(first - lo, last - lo)
        for whole, part in zip((out.phase, trusted, out.modulation, coarser), (band[0], band[1], band[2], band[4])):
            whole[first:last] = part[own]
        return first, last, lo, band

    def _depth_band(self, first: int, last: int, lo: int, band, blur: float, out: Reconstruction) -> None:
        """The second pass: depth, its noise, the kept pixels and XYZ of rows first to last."""
        phase, valid, _, noise_rad, coarser = band
        limits = np.array(
            [self.limits.max_depth_noise_mm, self.limits.max_depth_step_mm, self.limits.max_depth_bias_mm]
        )
        outputs = (out.depth_mm, out.quality, out.valid, out.xyz_mm)
        fused.trusted_points(
            phase,
            noise_rad,
            coarser,
            valid,
            lo,
            first,
            last,
            self._terms,
            self._slope,
            *self._rays,
            blur,
            limits,
            outputs,
        )


# Rows each band of PspReconstructor reads beyond its own: the phase noise pools 5 x 5 pixels (2 rows),
# the trust rules erode 1 and drop flying pixels 1 more; 8 leaves room for both.
BAND_HALO = 8


# The composite decoder names fringe orders on blocks of fused.BLOCK x fused.BLOCK pixels (2: the composite
# network's own stride): a code grating's phase changes over tens of pixels and the carrier's over one period
# (9 px in the default rig), so a block's summed phasors name its order as its pixels would, for a quarter of
# the work; each pixel's own carrier phase then takes the order nearest its block's absolute phase
# (docs/single-shot.md, orders on blocks).
# The composite's confidence is a vote over VOTE_WINDOW blocks (14 px), its orders checked against the median
# of MEDIAN_WINDOW blocks (10 px) around each, taken twice: on the composite set's validation split, with the
# shipped network and card, the windows that gave as many pixels as the per-pixel windows of 9 and 5 px did
# with no more errors (92.1% given; a vote over 5 blocks gave 0.3 point more with more errors, over 9 0.1 less)
VOTE_WINDOW, MEDIAN_WINDOW = 7, 5
# The decoder's diagnostics of its rig (min_separation, row_fit_error) look at every GRID_STEP-th pixel
# of every GRID_STEP-th row: both vary smoothly across the image.
GRID_STEP = 8
# The least separation of two orders' codes at which the composite decodes (rad: min_separation less twice
# row_fit_error, how far each order's predicted codes may stray). Its decisions keep half of it as their margin,
# and the shipped network's codes are off by 0.13-0.25 rad at their 95th percentile (a misaligned rig, runs/s85:
# 0.31 gave 83-86% of the lit pixels, none off; the default rig's 0.93, the geometry rigs' of
# scripts/single_shot_conditions.py at least 0.62 and 0.69). A projector whose rows move with depth (rolled against
# the baseline, or above or below the camera's axis) can make the codes repeat inside the working range (rolled 3
# degrees: 0.002), and a plane calibration that could not follow such rows between planes leaves its code models
# jumping (its rows' drift 9 rad off a straight line).
MIN_SEPARATION_RAD = 0.2
# A pixel whose codes name no order takes its neighbourhood's where this share of the VOTE_WINDOW keeps its
# own (CompositeDecoder; without it, rim pixels of a surface outside the range entered the roughness windows).
ADOPTION_VOTE = 0.75


def steps_16(low: np.ndarray, high: np.ndarray, spare: float) -> tuple[float, float]:
    """(base, step) that put every value from low to high, 0, and spare beyond either end, in 65536
    steps (median_16)."""
    base = min(0.0, float(low.min())) - spare
    return base, (float(high.max()) + spare - base) / 65535


def median_16_steps(phase: np.ndarray, base: float, step: float) -> np.ndarray:
    """cv2.medianBlur(phase, MEDIAN_WINDOW) as 16-bit steps, phase quantized as (phase - base) / step:
    quantizing keeps the phases' order, so the median of the steps is the median's step (base + steps x step)."""
    steps = cv2.addWeighted(phase, 1 / step, phase, 0, -base / step, dtype=cv2.CV_16U)
    return cv2.medianBlur(steps, MEDIAN_WINDOW)


def median_16(phase: np.ndarray, base: float, step: float) -> np.ndarray:
    """cv2.medianBlur(phase, MEDIAN_WINDOW) within step / 2 (median_16_steps)."""
    steps = median_16_steps(phase, base, step)
    return cv2.addWeighted(steps, step, steps, 0, base, dtype=cv2.CV_32F)


def block_means(x: np.ndarray) -> np.ndarray:
    """A map (H, W) averaged over CompositeDecoder's blocks (fused.BLOCK pixels a side; a last, partial
    block where H or W is odd: its pixels' mean)."""
    b, (height, width) = fused.BLOCK, x.shape
    padded = np.full((-(-height // b) * b, -(-width // b) * b), np.nan, np.float32)
    padded[:height, :width] = x
    return np.nanmean(padded.reshape(padded.shape[0] // b, b, -1, b), axis=(1, 3)).astype(np.float32)


class CodeMaps(NamedTuple):
    """CompositeDecoder's maps of one grid (the image's pixels, or its blocks): per code in the decoder's
    code_order (K, H, W) the intercept, rate and spacing of its predicted phase in the carrier phase;
    the lowest candidate's carrier phase, the working range's (low, high, with half an order to spare),
    and the coarse code's turn (rad of carrier phase)."""

    intercepts: np.ndarray
    rates: np.ndarray
    spacings: np.ndarray
    lowest: np.ndarray
    low: np.ndarray
    high: np.ndarray
    turn: np.ndarray

    def on_blocks(self) -> CodeMaps:
        """The same maps on CompositeDecoder's blocks."""
        return CodeMaps(*(np.stack([block_means(m) for m in a]) if a.ndim == 3 else block_means(a) for a in self))


class CompositeDecoder:
    """The composite pattern's phases (the carrier's and each code grating's) -> depth, for a
    calibration with code models.

    The orders are named on blocks of 2 x 2 pixels (fused.BLOCK), each with the sums of its pixels'
    phasors where they show fringes; each pixel's own carrier phase then takes the
    order nearest its block's absolute phase, and the rational model turns that into depth. Below,
    "pixel" is a block of that grid, windows are in blocks, and min_surface_px counts the image's pixels.

    Each pixel's carrier order is one of K consecutive orders that span the calibration's working
    range (with equal slack at both ends; K the coarsest code's orders). A code's phase is
    its row phase plus the absolute carrier phase / K_i, so each candidate order predicts it about
    2 pi / K_i from the next. Across the candidates the row phase drifts (the projector row a pixel
    sees moves with depth) almost linearly in the carrier phase: fitted so per pixel (row_fit_error:
    within a few 1e-3 rad in the default rig), each pixel's order follows in closed form (code_phase),
    coarse code first, as temporal unwrapping does with frequencies.
    min_separation is how close the codes of two orders of the working range come on this rig (rad,
    the root sum of squares over the codes): the margin every decision has is about half of it. Both
    are taken on a grid of the image's pixels (GRID_STEP).

    One pixel's code is noisy; a surface's is not: its absolute phase is smooth, and a wrong order is
    2 pi off. A pixel keeps its order only where it is the order nearest the median phase of the
    MEDIAN_WINDOW x MEDIAN_WINDOW pixels around it (taken twice). Its confidence is the lesser of two
    votes: the share of the pixels in the VOTE_WINDOW around it that keep their order so, and the share
    of its surface's (order_surfaces: the pixels joined to it through neighbours whose absolute phases
    differ by less than pi) that do; a surface with fewer than min_surface_px pixels whose codes name an
    order, or a pixel beside a step, has none. A patch of wrong orders inside a surface is cut off by
    the 2 pi steps around it and judged on its own codes; a wrong patch whose codes agree with it needs
    min_surface_px of them.
    A pixel whose codes name no order at all (too noisy to fit any candidate within the margin) takes
    the order nearest its neighbourhood's median phase where that lies in the working range and at
    least ADOPTION_VOTE of the VOTE_WINDOW keeps its own; it adds nothing to the votes, nor to its
    surface's size. Depth is NaN where a pixel's own codes name another order than its neighbourhood's,
    below min_confidence, where the image shows no fringes and where the order lies outside the working
    range (the nearest order inside would be wrong).
    An albedo striped like a code grating moves that code's phase over the whole stripes, and the
    surface's codes then agree on a wrong order. Given the image's code sidebands (code_sidebands), a
    surface more than half of whose pixels show sidebands of at least max_sideband has confidence 0.
    Beyond the working range the codes repeat (the coarse code's turn, shifted by each pixel's row
    drift), so a surface nearer or farther than the range names wrong orders inside it on bands of
    pixels, between bands whose codes name none. Of the pixels whose codes name no order of the range,
    those whose codes fit an order outside it closely (outside_phase) that their neighbours' fit too (within pi
    of the median around them) lie on a surface outside the range: a pixel where more than max_outside
    of the pixels with fringes around it (outside_share) do has confidence 0. Codes too noisy to name an
    order fit scattered orders outside it, which their neighbours' seldom share. In a frame where that
    refused more than BEYOND_WARNING of them, so does a surface whose codes fit an order outside the range
    more closely than the one it names at most of its blocks (outside_surfaces): a band of a far surface.
    A rig that moved since its calibration (a projector knocked) shifts every code a little, so that the
    codes miss the orders named all over the frame (misfit_of; DepthModel refuses such a frame).
    After each call: outside_range, the share of the blocks with fringes whose codes named no order
    of the working range (a scene too near or too far, or codes too noisy to tell); striped and beyond,
    the shares refused for their stripes and for lying on surfaces outside the range; taken, each pixel's
    absolute carrier phase, which misfit_of reads.
    """

    def __init__(
        self,
        calibration: Calibration,
        min_surface_px: int = 0,
        max_sideband: float = np.inf,
        max_outside: float = np.inf,
    ):
        self.min_surface_px, self.max_sideband, self.max_outside = min_surface_px, max_sideband, max_outside
        self.outside_range = self.striped = self.beyond = self.misfit = 0.0  # until the first call
        self.taken = None
        if not calibration.code_models:
            raise PhaseError("the composite decoder needs a calibration made with the composite pattern (code models)")
        if calibration.working_range_mm is None:
            raise PhaseError(
                "the calibration has no working range: calibrate again (fpp calibrate), or add "
                "working_range_mm: [near, far] (mm, where surfaces may be) to its file"
            )
        near, far = self.working_range_mm = calibration.working_range_mm
        cam = calibration.camera
        u, v = cam.ideal_pixels()
        ends = [np.broadcast_to(calibration.model.phase_at_depth(z, u, v), cam.shape) for z in (near, far)]
        span = np.abs(ends[1] - ends[0]) / TWO_PI
        orders = max(k for k, _ in COMPOSITE_CODES)
        if span.max() > orders - 1:
            raise PhaseError(
                f"the calibration's working range {near:g}-{far:g} mm spans up to {span.max():.1f} fringe orders; "
                f"the composite's code tells {orders} apart: narrow it (fpp calibrate --working-range)"
            )
        lowest = np.minimum(ends[0], ends[1]) - (orders - span) / 2 * TWO_PI
        middle = lowest + np.pi * orders
        # each code's row phase along the window, a straight line in the carrier phase per pixel (least squares)
        t = np.arange(orders + 1) - orders / 2
        self.code_order = sorted(range(len(COMPOSITE_CODES)), key=lambda i: -COMPOSITE_CODES[i][0])  # coarse first
        self.code_planes = np.array([2 + 2 * i for i in self.code_order])  # their numerators in a network's output
        terms, self.row_fit_error = [], 0.0  # per code in code_order: (intercept, rate, spacing)
        row = self._rows(calibration, u, v)
        on_grid = (slice(None, None, GRID_STEP),) * 2
        grid = self._rows(calibration, *(np.broadcast_to(a, cam.shape)[on_grid] for a in (u, v)))  # a lens: full maps
        for i in self.code_order:
            total = moment = 0.0  # running sums, not every order's map at once (67 of them: 160 MB)
            for k in t:
                r = row(i, middle + TWO_PI * k)
                total, moment = total + r, moment + k * r
            slope = moment / (np.sum(t * t) * TWO_PI)
            intercept = total / len(t) - slope * middle
            a, b, m = (x[on_grid] for x in (intercept, slope, middle))  # the fit's error on the grid
            self.row_fit_error = max(
                self.row_fit_error,
                *(float(np.abs(a + b * (m + TWO_PI * k) - grid(i, m + TWO_PI * k)).max()) for k in t),
            )
            rate = slope + 1 / COMPOSITE_CODES[i][0]  # d(predicted code) / d(carrier phase)
            terms.append((intercept, rate, TWO_PI * rate))
        self.min_separation = self._separation(grid, *(e[on_grid] for e in ends))
        if not self.min_separation - 2 * self.row_fit_error >= MIN_SEPARATION_RAD:
            raise PhaseError(
                f"on this rig the composite's codes of two orders of the working range {near:g}-{far:g} mm come "
                f"within {self.min_separation:.2f} rad of each other, and their rows' drift strays "
                f"{self.row_fit_error:.2f} rad from a straight line (twice that off the separation, at least "
                f"{MIN_SEPARATION_RAD} rad tells orders apart): the "
                "projector's rows move with depth (the projector rolled against the baseline, or above or below the "
                "camera's axis). Narrow the working range, move the projector a few mm up or down or turn it a degree "
                "(scripts/composite_alignment.py shows where on the default rig), calibrate from a board or from "
                "planes closer together (a plane calibration cannot follow rows that move half a turn of the coarse "
                "code from one plane to the next), or measure with the multi-shot path alone (patterns single_shot: "
                "paper)"
            )

        # the candidates' phases: inside the working range, with half an order to spare at each end; the
        # coarse code's turn per pixel (rad of carrier phase)
        low, high = np.minimum(ends[0], ends[1]) - np.pi, np.maximum(ends[0], ends[1]) + np.pi
        turn = TWO_PI * TWO_PI / terms[0][2]
        # how many of the coarse code's turns the candidates of a pixel span, from the lowest to the range's far
        # end: 2 in the default rig (31-43 orders a turn, 26 in the window); a projector above or below the
        # camera's axis moves the rows a pixel sees with depth, and a turn holds fewer orders (6 at 50 mm)
        self.coarse_turns = int(np.ceil(np.max((high - lowest) / np.abs(turn)))) + 1
        maps = [*(np.stack(m) for m in zip(*terms)), lowest, low, high, turn]
        self.pixel_maps = CodeMaps(
            *(np.ascontiguousarray(np.broadcast_to(m, m.shape[:-2] + cam.shape), np.float32) for m in maps)
        )
        self.block_maps = self.pixel_maps.on_blocks()
        # the turns of the coarse code that hold the orders of every depth from half the near end of the range
        # to infinity (where the phase converges)
        turns = [(calibration.model.phase_at_depth(z, u, v) - lowest) / turn for z in (near / 2, 1e9)]
        self.outside_turns = np.arange(np.floor(np.nanmin(turns)), np.ceil(np.nanmax(turns)), dtype=np.int64)
        self.terms = depth_terms(calibration)  # per pixel
        # the phases' median in 16 bits (median_16), a third of float32's time: every phase the median
        # sees (0 where no fringes, a turn either side of the range) in 65536 steps (about 0.01 rad); the
        # orders outside the range likewise (a finer code can move one 3 orders past its turn's window:
        # 0.03 rad steps in the default rig)
        self.median_steps = steps_16(low, high, 2 * TWO_PI)
        first, last = (lowest + turn * t for t in (self.outside_turns[0], self.outside_turns[-1] + 1))
        self.outside_steps = steps_16(np.minimum(first, last), np.maximum(first, last), 4 * TWO_PI)

    def maps(self, shape) -> CodeMaps:
        """The maps of the grid of that shape: the image's pixels or its blocks."""
        return self.pixel_maps if shape == self.pixel_maps.lowest.shape else self.block_maps

    def nearest_median(self, carrier: np.ndarray, phase: np.ndarray) -> np.ndarray:
        """The absolute phase of each pixel's order nearest the median of phase around it
        (median_16's steps, turned into phase in the same pass)."""
        base, step = self.median_steps
        return fused.nearest_order(carrier, median_16_steps(phase, base, step), base, step)

    @staticmethod
    def _rows(calibration: Calibration, u, v):
        """Each code's row phase at a carrier phase, at pixels (u, v): f(code, carrier phase)."""
        carrier, rows = calibration.model.at(u, v), calibration.code_row_phases(u, v)
        return lambda code, phase: rows(code, carrier.depth(phase))

    @staticmethod
    def _separation(row, near, far) -> float:
        """How close the codes of two orders in the working range come at some pixels (rad, the root sum
        of squares of each code's difference): row, their row phases (_rows); near and far, the phases
        the working range's ends give them."""
        lo, hi = np.minimum(near, far), np.maximum(near, far)
        codes, inside = [], []
        for k in range(int(np.ceil((hi - lo).max() / TWO_PI)) + 1):
            phase = lo + TWO_PI * k
            codes.append([row(i, phase) + phase / n for i, (n, _) in enumerate(COMPOSITE_CODES)])
            inside.append(phase <= hi)
        closest = np.inf
        for a in range(len(codes)):
            for b in range(a + 1, len(codes)):
                d = np.sqrt(sum(wrap_phase(ca - cb) ** 2 for ca, cb in zip(codes[a], codes[b])))
                closest = min(closest, float(np.where(inside[a] & inside[b], d, np.inf).min()))
        return closest

    def code_phase(self, carrier: np.ndarray, codes: list[np.ndarray]) -> np.ndarray:
        """Each pixel's absolute carrier phase as its own codes tell it.

        With code i's row phase a + b Phi, the j-th candidate Phi = lowest + 2 pi j predicts the code
        a + (b + 1/K_i) lowest + j s_i, s_i = 2 pi (b + 1/K_i). The coarse code fixes j up to its turns
        (the drift leaves 31-43 orders per turn across the image in the default rig, about as many as the
        working range spans), so a value of j fits it in each turn the candidates span (coarse_turns: 2
        there). From each, every finer code moves j to the nearest value it fits exactly
        (at most half a turn of that code away), and j rounded is a candidate. Of the candidates whose
        phase lies in the working range (half an order to spare at each end), the one all codes fit
        best (least sum of squared misses). A candidate whose codes miss by more than the decisions'
        margin (min_separation / 2, root sum of squares) is none: where no candidate is left, NaN. So
        a surface outside the working range says NaN, not the nearest order inside (with exact codes:
        every pixel of planes from 50 mm before the range to 100 mm beyond it, in the default rig;
        further out the codes begin to repeat). Per pixel in one compiled pass (fused.code_phase)."""
        m = self.maps(carrier.shape)
        ordered = np.stack([codes[i] for i in self.code_order])
        return fused.code_phase(
            carrier,
            ordered,
            m.intercepts,
            m.rates,
            m.spacings,
            m.lowest,
            m.low,
            m.high,
            self.min_separation / 2,
            self.coarse_turns,
        )

    def outside_phase(self, carrier: np.ndarray, codes: list[np.ndarray], where: np.ndarray) -> np.ndarray:
        """At pixels where (flat indices), the absolute carrier phase of the order outside the working
        range that their codes fit best within OUTSIDE_FIT of code_phase's margin: its candidates a turn of the coarse
        code further each time through outside_turns (the orders of every depth from half the range's
        near end on), one per turn (fused.outside_phase). NaN where none fits."""
        m = self.maps(carrier.shape)

        def flat(a):  # a map (or a stack of maps) as rows of pixels, not copied
            return a.reshape(*a.shape[:-2], -1)

        return fused.outside_phase(
            where,
            flat(carrier),
            np.stack([flat(codes[i]) for i in self.code_order]),
            *(flat(a) for a in (m.intercepts, m.rates, m.spacings, m.lowest, m.turn, m.low, m.high)),
            self.outside_turns,
            OUTSIDE_FIT * self.min_separation / 2,
        )

    def beyond_range(self, carrier, codes, unsure: np.ndarray, fringes: np.ndarray) -> np.ndarray:
        """Pixels among the surfaces outside the working range: where more than max_outside of the pixels
        with fringes around them (outside_share) are pixels of unsure (flat indices of those whose codes
        name no order of the range) whose codes fit an order outside it within pi of the median of the
        fits around them (0 where none)."""
        outside = np.zeros(carrier.shape, np.float32)
        fit = self.outside_phase(carrier, codes, unsure)
        found = np.isfinite(fit)
        fit, unsure = fit[found], unsure[found]
        np.put(outside, unsure, fit)
        median = median_16(outside, *self.outside_steps).ravel()[unsure]
        agreeing = np.zeros(carrier.shape, bool)
        np.put(agreeing, unsure[np.abs(fit - median) < np.pi], True)
        return outside_share(agreeing, fringes, OUTSIDE_BLOCK // fused.BLOCK) > self.max_outside

    def range_warning(self) -> str | None:
        """After a call: what to say where more than OUTSIDE_WARNING of the pixels with fringes named no
        order of the working range (outside_range) or more than BEYOND_WARNING were refused where the
        codes repeat beyond it (beyond); None where neither."""
        if self.outside_range <= OUTSIDE_WARNING and self.beyond <= BEYOND_WARNING:
            return None
        near, far = self.working_range_mm
        refused = (
            f" (and {self.beyond:.1%} more were refused where they repeat beyond it; depth beside those may be "
            "an order off)"
            if round(self.beyond, 3)
            else ""
        )
        return (
            f"the codes of {self.outside_range:.0%} of the pixels with fringes name no order of the working range "
            f"{near:g}-{far:g} mm{refused}: is the scene, or part of it, nearer or farther, are its codes "
            "unreadable, or is the frame not the composite (a phase-shift pattern's: fed the camera's stream while "
            "the projector shows the whole sequence, take fringe_single or show the composite alone)?"
        )

    def __call__(
        self,
        out: np.ndarray,
        min_confidence: float,
        fringes: np.ndarray | None = None,
        sidebands: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """out: (2 + 2 x codes, H, W) the carrier's numerator and denominator, then each code's; fringes:
        the pixels that show fringes (default all); sidebands: code_sidebands of the fringe image out
        was read from (without them, no stripes rule). Returns (depth mm, confidence), NaN where unknown."""
        out = np.ascontiguousarray(out, np.float32)
        if fringes is None:
            fringes = np.ones(out.shape[1:], bool)
        # a block's phasors: the sums of its pixels' that show fringes (of a phasor, only the angle counts)
        phasors, shown = fused.block_phasors(out, fringes)
        if sidebands is not None:  # smooth (a window of about 24 px): its value at each block's corner
            sidebands = sidebands[:: fused.BLOCK, :: fused.BLOCK]
        absolute, confidence = self.block_orders(list(phasors), min_confidence, shown, sidebands)
        m = self.pixel_maps
        depth, confidence, taken, missed = fused.block_depth(
            out, absolute, confidence, fringes, self.code_planes, m.intercepts, m.rates, *self.terms
        )
        # a pixel whose own codes name another order than its block's (one across a step from most of its block) is
        # refused; codes that fit the block's within the decisions' margin name no other, so only the others are asked
        where = np.flatnonzero((missed > np.float32((self.min_separation / 2) ** 2)) & fringes)
        other = np.abs(self.pixel_code_phase(out, where) - taken.ravel()[where]) >= np.pi  # not where they name none
        depth.ravel()[where[other]] = np.nan
        self.taken = taken
        return depth, confidence

    def misfit_of(self, out: np.ndarray, depth: np.ndarray) -> float:
        """After a call on out, at the pixels depth (its output, after every rule) keeps: how far the rig seems
        to have moved since its calibration: the smooth_miss of each code's signed miss of the order named, at
        every MISFIT_STEP-th pixel (rad; 0 where fewer than MISFIT_SHARE of those pixels keep a depth). Kept as
        misfit."""
        grid = (slice(None, None, MISFIT_STEP),) * 2
        given = np.isfinite(depth[grid])
        self.misfit = 0.0
        if given.mean() >= MISFIT_SHARE:
            taken, m, misses = self.taken[grid][given], self.pixel_maps, []
            for k, plane in enumerate(self.code_planes):
                code = np.arctan2(out[plane][grid][given], out[plane + 1][grid][given])
                misses.append(wrap_phase(code - m.intercepts[k][grid][given] - m.rates[k][grid][given] * taken))
            self.misfit = smooth_miss(misses, given)
        return self.misfit

    def pixel_code_phase(self, out: np.ndarray, where: np.ndarray) -> np.ndarray:
        """code_phase at the image's pixels where (flat indices), from out's phasors there."""
        phasors = out.reshape(len(out), -1)[:, where]
        carrier, *codes = (np.arctan2(num, den)[None] for num, den in zip(phasors[0::2], phasors[1::2]))
        m = self.pixel_maps
        maps = (m.intercepts, m.rates, m.spacings, m.lowest, m.low, m.high)  # code_phase's, as a row (.., 1, n)
        ordered = np.stack([codes[i] for i in self.code_order])
        row = [a.reshape(*a.shape[:-2], 1, -1)[..., where] for a in maps]
        return fused.code_phase(carrier, ordered, *row, self.min_separation / 2, self.coarse_turns)[0]

    def code_miss(self, codes: list, phase: np.ndarray, where: np.ndarray) -> np.ndarray:
        """At the blocks where (flat indices), how far their codes miss the codes an absolute carrier phase (one
        per block) predicts: the sum over the codes of the squared (wrapped) miss."""
        m, total = self.block_maps, np.zeros(where.size, np.float32)
        for k, i in enumerate(self.code_order):
            predicted = m.intercepts[k].ravel()[where] + m.rates[k].ravel()[where] * phase
            total += wrap_phase(codes[i].ravel()[where] - predicted) ** 2
        return total

    def outside_surfaces(self, carrier, codes, absolute, surface, counted, count: int) -> np.ndarray:
        """Per surface label (0 .. count - 1), whether it lies outside the working range though its codes name an
        order inside: at more than half of its counted blocks the codes fit an order outside the range
        (outside_phase) more closely than the order the surface names there (absolute). Beyond the range the
        codes repeat, and a far surface's fit a wrong order inside it on bands within the decisions' margin,
        while they fit their own order outside it as closely as a surface inside the range fits its own."""
        where = np.flatnonzero(counted)
        fit = self.outside_phase(carrier, codes, where)
        found = np.isfinite(fit)
        where, fit = where[found], fit[found]
        closer = where[self.code_miss(codes, fit, where) < self.code_miss(codes, absolute.ravel()[where], where)]
        blocks = np.bincount(surface[counted], minlength=count)
        return np.bincount(surface.ravel()[closer], minlength=count) > blocks / 2

    def block_orders(
        self, phasors: list, min_confidence: float, fringes: np.ndarray, sidebands: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """__call__ on the blocks' grid: (absolute carrier phase, NaN where unknown; confidence)."""
        carrier, *codes = (cv2.phase(den, num) for num, den in zip(phasors[0::2], phasors[1::2]))
        own = self.code_phase(carrier, codes)
        ordered = fringes & np.isfinite(own)  # own is NaN where the codes name an order out of range
        shown = np.count_nonzero(fringes)
        self.outside_range = (shown - np.count_nonzero(ordered)) / max(shown, 1)
        local = np.where(ordered, own, np.float32(0))
        for _ in range(2):  # the order nearest the neighbourhood's median phase
            local = self.nearest_median(carrier, local)
        agree = (np.abs(own - local) < np.pi) & ordered
        vote = cv2.boxFilter(agree.astype(np.float32), -1, (VOTE_WINDOW, VOTE_WINDOW), borderType=cv2.BORDER_REPLICATE)
        # codes too noisy to name any order (not a contradicting one): the neighbourhood's, inside the range
        unsure = np.flatnonzero(fringes & ~ordered)  # a few: indices, not whole-image passes
        beyond = np.zeros_like(fringes)
        if np.isfinite(self.max_outside) and unsure.size:
            beyond = self.beyond_range(carrier, codes, unsure, fringes)
        order = local.ravel()[unsure]
        low, high = self.block_maps.low.ravel()[unsure], self.block_maps.high.ravel()[unsure]
        inside = (order >= low) & (order <= high)
        adopted = unsure[inside & (vote.ravel()[unsure] >= ADOPTION_VOTE)]
        np.put(own, adopted, local.ravel()[adopted])
        np.put(ordered, adopted, True)
        surface, size = order_surfaces(local, ordered)
        agreeing = fused.label_counts(surface, size.size, agree)
        counted = agree.copy()  # the blocks whose own codes name the order kept, before adopted ones join
        np.put(agree, adopted, True)  # kept, after the votes
        self.beyond = np.count_nonzero(beyond & agree) / max(shown, 1)  # the orders it takes away
        share = (agreeing / np.maximum(size, 1)).astype(np.float32)
        share[0] = 0  # label 0: beside a step, on no surface
        coded = size - np.bincount(surface.ravel()[adopted], minlength=size.size)  # adopted pixels make no surface
        share[coded * fused.BLOCK**2 < self.min_surface_px] = 0
        self.striped = 0.0
        if sidebands is not None and np.isfinite(self.max_sideband):
            striped = np.bincount(surface[sidebands >= self.max_sideband], minlength=size.size) > size / 2
            striped &= share > 0  # on a surface (not label 0) whose vote counts
            share[striped] = 0
            self.striped = float(np.sum(size[striped])) / max(shown, 1)
        # surfaces outside the range were found: may others name orders inside it? (after the stripes, the reason
        # a user is told where both apply)
        if self.beyond > BEYOND_WARNING:
            share[self.outside_surfaces(carrier, codes, local, surface, counted, size.size)] = 0
        confidence = np.minimum(vote, np.take(share, surface))
        confidence[beyond] = 0
        np.copyto(own, np.float32(np.nan), where=~(agree & (confidence >= min_confidence)) | beyond)
        return own, confidence


# A rig that moved since its calibration (a projector knocked): CompositeDecoder.misfit_of over a frame's output.
# As calibrated at most 0.060 rad on the 200 validation scenes (median 0.011), and 0.050 on 30 scenes under
# photometry beyond training (throwaway runs/s86/misfit_product.py); a projector rolled 0.05-0.5 degree or moved
# 10-20 mm up or down 0.108-0.258, where without the rule up to 72.5% of the output was off by more than 1 mm
# (scripts/knocked_rig.py). Beyond MAX_MISFIT_RAD, DepthModel gives the frame no depth and says why.
MAX_MISFIT_RAD, MISFIT_STEP, MISFIT_SHARE = 0.08, 8, 0.05


def smooth_miss(misses: list[np.ndarray], where: np.ndarray, within: float = np.inf) -> float:
    """How far codes miss smoothly over an image (rad): each code's signed misses at the pixels where (a mask
    of the image, or of a grid over it), a plane fitted to them over the image, and the fitted planes' RMS
    there, root sum of squares over the codes. A rig moved since its calibration moves the projector rows
    its pixels see smoothly, and every code with them; noise, outlines and textures scatter the misses both
    ways and fit no plane. With within finite, the planes are fitted twice again, each time to the pixels
    whose misses all lie within that of the last planes: codes read by FTP stray by radians at
    outlines and in clipped or dark patches, which pull a least-squares plane."""
    rows, cols = np.nonzero(where)
    basis = np.stack([np.ones(cols.size), cols / where.shape[1], rows / where.shape[0]], 1)
    kept = np.ones(cols.size, bool)
    for _ in range(3 if np.isfinite(within) else 1):
        fits = [basis @ np.linalg.lstsq(basis[kept], miss[kept], rcond=None)[0] for miss in misses]
        kept = np.all([np.abs(miss - fit) < within for miss, fit in zip(misses, fits)], axis=0)
        if np.count_nonzero(kept) < basis.shape[1]:
            break
    return float(np.sqrt(sum(np.mean(fit**2) for fit in fits)))


# more than this share of the pixels with fringes naming no order of the working range: the scene, or part of
# it, is outside it (chosen on validation, every surface in the range: 1 frame in 200 passes it; beyond the
# range the codes repeat and name wrong orders inside it on much of a surface, docs/single-shot.md)
OUTSIDE_WARNING = 0.3
# or more than this share of them refused for naming orders inside the range where the codes repeat beyond it
# (CompositeDecoder.beyond): objects standing in the range before a far wall, whose fringes mostly name orders
# of the range (the shipped network on validation, every surface in the range: at most 0.14% in its 200
# frames; 5-41% on frames of exploration seeds with surfaces outside it; docs/single-shot.md)
BEYOND_WARNING = 0.01


# An order outside the working range counts only where the codes fit it within this share of the decisions'
# margin: a surface beyond the range is read as well as one inside (0.02-0.04 rad on far planes) and fits its
# repeated order closely; codes too noisy to name an order of the range fit some order outside it only
# loosely. On validation (every surface in the range) the fast separable network's false alarms, all at the
# frame's edge, went from 6.2e-5 of the output at the whole margin to none at 0.4 (docs/single-shot.md).
OUTSIDE_FIT = 0.4

# The window outside_share takes: OUTSIDE_WINDOW blocks of OUTSIDE_BLOCK pixels (120 px), about two of the
# bands an out-of-range plane names orders on and none (30-70 px each in the default rig).
OUTSIDE_BLOCK, OUTSIDE_WINDOW = 8, 15


def outside_share(outside: np.ndarray, fringes: np.ndarray, block: int) -> np.ndarray:
    """Per pixel, the share of the pixels with fringes in the window around it (OUTSIDE_WINDOW blocks of
    block pixels) that are pixels of outside (a mask); taken on blocks and resized back."""
    height, width = fringes.shape
    small = (max(width // block, 1), max(height // block, 1))
    sums = [
        cv2.boxFilter(
            cv2.resize(mask.astype(np.float32), small, interpolation=cv2.INTER_AREA),
            -1,
            (OUTSIDE_WINDOW, OUTSIDE_WINDOW),
            normalize=False,
            borderType=cv2.BORDER_CONSTANT,
        )
        for mask in (outside, fringes)
    ]
    share = sums[0] / np.maximum(sums[1], np.float32(1e-6))
    return cv2.resize(share, (width, height), interpolation=cv2.INTER_LINEAR)


def order_surfaces(absolute: np.ndarray, fringes: np.ndarray, max_step: float = np.pi) -> tuple[np.ndarray, np.ndarray]:
    """(label per pixel, pixels per label) of the surfaces an absolute phase map holds: pixels with
    fringes joined through their 4 neighbours where the absolute phase changes by less than pi (Itoh's
    condition, which a continuous surface meets: the orders step as the wrapped phase does). A pixel
    beside a change of more (a depth step, or an order that disagrees with its neighbour's) is on
    none: label 0, counted as no pixels. max_step: the same for another map (a depth map: half an
    order's depth)."""
    inside = fringes & drop_flying_pixels(absolute, max_step)
    count, labels = cv2.connectedComponents(inside.view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
    return labels, fused.label_counts(labels, count, inside)


# The sidebands are summed over blocks of SIDEBAND_BLOCK pixels (16x fewer to window) and windowed there by a
# tent SIDEBAND_TENT blocks wide (two boxes, cv2.stackBlur: the same time at any width; variance
# 2 ((r + 1)^2 - 1) / 12 for a width 2 r + 1: a sigma of 6.1 blocks, 24 pixels, 2.7 of the default rig's
# carrier periods). A Gaussian of sigma 6 px let the coarse code's own lobe into them (0.09 on a plain
# plane); from 10 px it did not.
SIDEBAND_BLOCK, SIDEBAND_TENT = 4, 29


def code_sidebands(image: np.ndarray, out: np.ndarray) -> np.ndarray:
    """How much the carrier's amplitude swings with a code grating, per pixel: the image less its local
    mean, demodulated at the carrier's phase plus and minus each code's (the phases out gives: the
    carrier's numerator and denominator, then each code's), over a window of about 24 pixels, less
    what the carrier's own demodulation times the code's mean phasor over the window explains (where
    the network cannot read a code, in heavy defocus, its phase varies slowly and would carry the
    carrier into the sidebands); the mean of each pair against the carrier's own, the larger over the
    codes.
    Projected light only adds, so the composite's gratings make no such sidebands. An albedo multiplies
    all of them: stripes of contrast c laid like a code give (c/4) / (1 - c/2) (0.21 at c = 0.6), and
    add a lobe of 5 times that of the carrier's amplitude where the code is read (the code's own:
    CODE_AMPLITUDE / CARRIER_AMPLITUDE = 0.75), which moves the code's phase. Computed on blocks
    (fused.demodulated_blocks) and resized back."""
    height, width = image.shape
    small = (width // SIDEBAND_BLOCK, height // SIDEBAND_BLOCK)

    def window(x):  # a tent of two boxes (cv2.stackBlur: the same time at any width) for the Gaussian
        return cv2.stackBlur(x, (SIDEBAND_TENT, SIDEBAND_TENT))

    mean = window(cv2.resize(image.astype(np.float32), small, interpolation=cv2.INTER_AREA))
    light = cv2.subtract(image, cv2.resize(mean, (width, height)), dtype=cv2.CV_32F)
    sums = fused.demodulated_blocks(light, out, SIDEBAND_BLOCK)  # (planes, 2, rows, cols)
    sums = window(np.ascontiguousarray(sums.reshape(-1, *sums.shape[2:]).transpose(1, 2, 0)))  # all at once
    ratio = fused.sideband_ratio(sums, SIDEBAND_BLOCK**2)
    return cv2.resize(ratio, image.shape[::-1], interpolation=cv2.INTER_LINEAR)


FTP_MIN_CONFIDENCE = 0.5  # the composite by FTP: not tuned (a baseline), half the neighbourhood agrees


def composite_ftp_phases(image: np.ndarray, calibration: Calibration):
    """(carrier phase, [each code's phase], carrier lobe amplitude) of a composite image by FTP, each
    lobe where the calibration puts it at the reference depth (the median phase slope, in cycles per
    image)."""
    cal = calibration
    u, v = cal.camera.ideal_pixels()
    carrier = cal.model.phase_at_depth(cal.reference_depth_mm, u, v) * np.ones(image.shape)
    codes = ftp_code_phases(
        image, [spectral_centre(c) for c in cal.code_phases_at_depth(cal.reference_depth_mm, carrier, u, v)]
    )
    vertical, cycles = carrier_lobe(carrier)
    carrier, amplitude = ftp_wrapped_phase(image, vertical, carrier=cycles)
    return carrier, codes, amplitude


# A rig that still fits its calibration: a composite frame's codes miss its code models smoothly (CodeFit) by at most
# 0.066 rad on 24 fresh scenes of every family under the training's random photometry (scripts/knocked_rig.py), and
# 0.047 on 40 under photometry beyond it (throwaway runs/s88/codefit_probe.py); a projector rolled 0.1 degree since,
# 0.255-0.260 rad and the multi-shot depth 0.3 mm off; 0.05 degree, 0.126-0.132 and 0.15 mm. Three times the worst as
# calibrated. (The median miss, before: up to 0.385 rad as calibrated, so a limit of 0.3, and rolls under 0.2 degree
# went unsaid.) Misses further than CODE_FIT_WITHIN from the fitted planes are FTP's strays, not the rig's.
MAX_CODE_MISFIT_RAD, CODE_FIT_WITHIN = 0.2, 0.5


class CodeFit:
    """Whether a rig still fits its calibration, from one sequence: how far the composite frame's code
    gratings (FTP) miss the phases the calibration's code models give them at the multi-shot depth and
    phase, smoothly over the image (smooth_miss, at every MISFIT_STEP-th pixel with depth; rad). A
    projector rolled (or moved tens of millimetres up or down) since calibrating moves the rows its
    pixels see and the codes with them, where the multi-shot depth alone cannot tell (a roll of 0.1
    degree put it 0.3 mm off); one moved along the baseline is not seen."""

    MIN_SHARE = 0.1

    def __init__(self, calibration: Calibration):
        self.calibration = calibration
        self.u, self.v = calibration.camera.ideal_pixels()
        at = calibration.reference_depth_mm
        carrier = np.broadcast_to(calibration.model.phase_at_depth(at, self.u, self.v), calibration.camera.shape)
        self.centres = [spectral_centre(c) for c in calibration.code_phases_at_depth(at, carrier, self.u, self.v)]

    def __call__(self, image: np.ndarray, depth_mm: np.ndarray, phase: np.ndarray) -> float:
        """The misfit of a composite frame with its sequence's depth and phase; NaN where less than
        MIN_SHARE of the pixels have depth (too few to tell)."""
        grid = (slice(None, None, MISFIT_STEP),) * 2
        known = np.isfinite(depth_mm[grid])
        if known.mean() < self.MIN_SHARE:
            return float("nan")
        u, v = (np.broadcast_to(a, depth_mm.shape)[grid][known] for a in (self.u, self.v))
        predicted = self.calibration.code_phases_at_depth(depth_mm[grid][known], phase[grid][known], u, v)
        codes = ftp_code_phases(image, self.centres)
        return smooth_miss([wrap_phase(c[grid][known] - p) for c, p in zip(codes, predicted)], known, CODE_FIT_WITHIN)


def spectral_centre(phase: np.ndarray) -> tuple[float, float]:
    """Where a smooth phase map's fringes sit in the image's spectrum: its median gradient, in cycles per
    image width and height (signed: the lobe whose phase is the map's)."""
    h, w = phase.shape
    return float(np.median(np.diff(phase, axis=1)) * w / TWO_PI), float(np.median(np.diff(phase, axis=0)) * h / TWO_PI)


def carrier_lobe(carrier: np.ndarray) -> tuple[bool, float]:
    """(vertical, cycles) of a carrier phase map, as ftp_wrapped_phase takes them: whether its fringes
    stand vertical in the image (its phase runs along the rows more than down the columns, per pixel; a
    camera mounted turned a quarter sees them lying), and its cycles across the image that way (negative
    where its phase falls: a mirrored projector)."""
    (fx, fy), (h, w) = spectral_centre(carrier), carrier.shape
    vertical = abs(fx) / w >= abs(fy) / h
    return vertical, fx if vertical else fy


def reconstruct_ftp(
    image: np.ndarray,
    calibration: Calibration,
    limits: QualityLimits = QualityLimits(),
    decoder: CompositeDecoder | None = None,
) -> Reconstruction:
    """Single-shot baseline: Takeda's FTP wrapped phase, then the same rational model.

    With the composite (a calibration with code models) the code gratings' own lobes tell each
    pixel's fringe order through decoder (a CompositeDecoder for this calibration and the working
    range: made once by the caller, it is costly to make); the lobes are taken where the calibration
    puts them at the reference depth. With the paper's image there is no order to tell: the phase is
    unwrapped spatially, and the global multiple of 2 pi is chosen to put the median pixel at the
    calibration's reference depth (the background), as a reference-plane FTP set-up does.
    """
    cal = calibration
    image = np.asarray(image)
    if image.shape != cal.camera.shape:
        raise PhaseError(f"expected one {cal.camera.width}x{cal.camera.height} image, got shape {image.shape}")
    image = cal.camera.full_range(image)
    u, v = cal.camera.ideal_pixels()
    if cal.code_models:
        if decoder is None:
            raise PhaseError("the composite's FTP needs a CompositeDecoder for the working range its code spans")
        carrier, codes, amplitude = composite_ftp_phases(image, cal)
        fringes = amplitude >= limits.min_modulation * full_scale(image.dtype)
        out = np.stack([f(p) for p in (carrier, *codes) for f in (np.sin, np.cos)])
        depth, _ = decoder(out, FTP_MIN_CONFIDENCE, fringes)
        depth, valid = trusted_depth(depth, np.isfinite(depth), limits.max_depth_step_mm)
        phase = cal.model.phase_at_depth(depth, u, v)
        return Reconstruction(
            depth, back_project(depth, cal.camera), valid, amplitude.astype(np.float32), phase.astype(np.float32)
        )
    reference = cal.model.phase_at_depth(cal.reference_depth_mm, u, v) * np.ones(image.shape)
    vertical, cycles = carrier_lobe(reference)
    wrapped, amplitude = ftp_wrapped_phase(image, vertical)
    if cycles < 0:  # the lobe found grows along +x (+y); the projector's phase falls that way
        wrapped = np.mod(-wrapped, TWO_PI)
    phase = unwrap_spatial(wrapped)
    phase += TWO_PI * np.rint(np.median(reference - phase) / TWO_PI)
    valid = amplitude >= limits.min_modulation * full_scale(image.dtype)
    depth, valid = trusted_depth(cal.model.depth(phase, u, v).astype(np.float32), valid, limits.max_depth_step_mm)
    return Reconstruction(
        depth, back_project(depth, cal.camera), valid, amplitude.astype(np.float32), phase.astype(np.float32)
    )
