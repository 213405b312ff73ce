"""The steps a user strings together, as functions: calibrate from planes, and the simulated
calibrate-then-measure experiment behind the demo, the tests and the README's numbers."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .calibration import Calibration, CalibrationError, CameraIntrinsics, RationalModel, fit_rational_model
from .metrics import DepthErrors, depth_errors, noise_limited_depth_std
from .patterns import COMPOSITE_CODES, PatternSet
from .phase import TWO_PI, code_lobe_centres, ftp_code_phases, unwrap_spatial, wrap_phase
from .reconstruct import QualityLimits, Reconstruction, multi_frequency_phase
from .scenes import SURFACE_DEPTH_MM, make_scene, plane_scene
from .simulation import Rig, render

CALIBRATION_DEPTHS_MM = (1100.0, 1150.0, 1200.0, 1250.0, 1300.0)


# A plane's pixels that calibrate: phase noise at most this (no depth model yet to say it in mm); about
# 0.1 mm of depth at the default rig, several times what a well-lit plane's pixels have.
CALIBRATION_MAX_PHASE_NOISE_RAD = 0.05


def calibrate_from_planes(
    stacks,
    depths_mm,
    camera: CameraIntrinsics,
    patterns: PatternSet,
    reference_depth_mm: float | None = None,
    sample_step: int = 4,
    limits: QualityLimits = QualityLimits(),
    working_range_mm: tuple[float, float] | None = None,
):
    """Fit the rational model from fringe stacks of flat planes square to the camera at known depths
    (a plate on a translation stage). Returns (calibration, fit RMSE in mm per plane). The working
    range is the planes' depths unless given.

    Every sample_step-th trusted pixel of every plane is a sample (u, v, phi, z). With the composite
    single-shot frame, the code model is fitted the same way to the row phase plus the carrier's
    phase on each plane (calibration.Calibration).
    """
    if len(stacks) != len(depths_mm):
        raise CalibrationError(f"{len(stacks)} captures but {len(depths_mm)} depths")
    if len(set(depths_mm)) < 3:
        raise CalibrationError(f"need planes at three or more different depths, got {sorted(set(depths_mm))}")
    ideal_u, ideal_v = (np.broadcast_to(c, camera.shape) for c in camera.ideal_pixels())  # the model's (u, v)
    samples, rows, phases = [], [], []  # per plane: its samples, each code's row phase, the carrier's phase
    for images, z in zip(stacks, depths_mm):
        images = np.asarray(images)
        if images.shape[1:] != camera.shape:
            raise CalibrationError(
                f"plane at {z} mm: images are {images.shape[2]}x{images.shape[1]}, "
                f"the camera is {camera.width}x{camera.height}"
            )
        images = camera.full_range(images)
        phase, valid, _, noise, _ = multi_frequency_phase(images, patterns, limits)
        valid &= noise <= CALIBRATION_MAX_PHASE_NOISE_RAD
        v, u = np.nonzero(valid)
        if u.size < 100:
            raise CalibrationError(f"plane at {z} mm: only {u.size} usable pixels (no fringes visible?)")
        keep = slice(None, None, sample_step)
        u, v = ideal_u[v[keep], u[keep]], ideal_v[v[keep], u[keep]]
        samples.append((u, v, phase[valid][keep], np.full(u.size, float(z))))
        if patterns.single_shot == "composite":
            rows.append(code_row_phases(images[patterns.single_shot_index], phase, valid))
            phases.append(phase)
    u, v, phase, depth = (np.concatenate(parts) for parts in zip(*samples))
    model = fit_rational_model(u, v, phase, depth)
    residuals = [float(np.sqrt(np.mean((model.depth(p, uu, vv) - z) ** 2))) for uu, vv, p, z in samples]
    reference = float(np.median(depths_mm)) if reference_depth_mm is None else float(reference_depth_mm)
    code_models = []
    keep = (slice(None, None, sample_step),) * 2
    u, v = (np.tile(a[keep].ravel(), len(stacks)) for a in (ideal_u, ideal_v))
    aligned = aligned_rows(rows, depths_mm) if rows else []
    code_samples = [[row + phase for row in plane] for plane, phase in zip(aligned, phases)]
    for code in zip(*code_samples):  # each code's samples on every plane
        chi = np.concatenate([c[keep].ravel() for c in code])
        code_models.append(fit_code_model(u, v, chi, np.repeat(np.asarray(depths_mm, float), chi.size // len(code))))
    working_range = working_range_mm or (min(depths_mm), max(depths_mm))
    return Calibration(camera, model, patterns, reference, code_models, working_range), residuals


def aligned_rows(rows: list, depths_mm) -> list:
    """The planes' code row phases (rows[plane][code], code_row_phases', each a whole number of turns
    off) with the turns that keep each plane's where the planes before it say the rows are heading:
    planes in depth order, the coarse code's rows nearest the last step's drift carried on (in 1 /
    depth), the finer codes' nearest the coarse code's drift (the codes see the same projector row, P_i
    pixels a turn). A projector beside the camera's axis sees nearly the same row at every depth; one
    20 mm above it moves the rows a pixel sees by 20 px over 200 mm, half a turn of the fine code from
    one plane to the next, and a projector rolled a few degrees moves them with the carrier (taking the
    first plane's turn for every plane refused both)."""
    periods = [period for _, period in COMPOSITE_CODES]
    coarse = int(np.argmax(periods))

    def nearest(row, expected):  # row moved by the whole turns that bring it nearest expected
        return row + TWO_PI * np.rint(np.nanmedian(expected - row) / TWO_PI)

    order = np.argsort(depths_mm)
    aligned, drift = {order[0]: rows[order[0]]}, 0.0  # drift: the coarse rows' last step per unit of 1 / depth
    for before, plane in zip(order, order[1:]):
        step = 1 / depths_mm[plane] - 1 / depths_mm[before]
        moved = nearest(rows[plane][coarse], aligned[before][coarse] + drift * step) - aligned[before][coarse]
        aligned[plane] = [
            nearest(row, previous + moved * periods[coarse] / period)
            for row, previous, period in zip(rows[plane], aligned[before], periods)
        ]
        drift = moved / step
    return [aligned[plane] for plane in range(len(rows))]


# A code grating's row phase on a plane is unwrapped across the plane, and where FTP cannot read the code (a
# dark spot) the unwrapping can leave a region of the plane a whole turn off: its samples are taken back the
# turns their code's model says, and samples still off it by more than CODE_SLIP_RAD are left out of its fit.
# Simulated planes fit to 0.01-0.02 rad RMS (defocus 2 px; at most 0.09 rad in a thousand samples), against the
# decoder's 0.47 rad of margin for each order: a calibration whose codes fit worse than CODE_FIT_MAX_RAD, or
# with more than CODE_SLIP_MAX of the samples left out, is refused.
CODE_SLIP_RAD, CODE_FIT_MAX_RAD, CODE_SLIP_MAX = 1.0, 0.1, 0.05


def fit_code_model(u, v, chi, depth) -> RationalModel:
    """A code grating's rational model from its samples on the planes (chi: its row phase plus the carrier's
    phase), fitted again without those off it by more than CODE_SLIP_RAD until they stay the same, then so with
    each sample taken back the whole turns it is off the fit."""
    sampled = np.isfinite(chi)
    kept, turns = sampled, np.zeros(chi.shape)
    for take_back in (False, True):  # first without the samples a turn off, then with them taken back
        for _ in range(5):
            model = fit_rational_model(u[kept], v[kept], (chi - turns)[kept], depth[kept])
            miss = np.where(sampled, chi - model.phase_at_depth(depth, u, v), 0)
            turns = TWO_PI * np.rint(miss / TWO_PI) * take_back
            fitting = sampled & (np.abs(miss - turns) <= CODE_SLIP_RAD)
            if np.array_equal(fitting, kept):
                break
            kept = fitting
    rms = np.sqrt(np.mean((miss - turns)[kept] ** 2))
    left_out = 1 - np.count_nonzero(kept) / np.count_nonzero(sampled)
    if not (rms <= CODE_FIT_MAX_RAD and left_out <= CODE_SLIP_MAX):
        raise CalibrationError(
            f"the composite frame's code gratings fit their model on the planes to {rms:.2f} rad RMS (at most "
            f"{CODE_FIT_MAX_RAD}) with {left_out:.1%} of the samples off by more than {CODE_SLIP_RAD} rad (at most "
            f"{CODE_SLIP_MAX:.0%}): check the planes' focus and exposure, and that each is flat and whole, or "
            "calibrate with a board (fpp calibrate --board), whose code models come from the projector's geometry"
        )
    return model


CODE_BORDER_PX = 24  # FTP is unreliable this near the image's and the lit area's edges


def code_row_phases(composite: np.ndarray, phase: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
    """Each code grating's row phase on a plane (its FTP phase less the carrier's absolute phase / K),
    unwrapped across the plane; NaN near edges and where the multi-shot phase is untrusted."""
    inner = cv2.erode(
        valid.astype(np.uint8),
        np.ones((2 * CODE_BORDER_PX + 1,) * 2, np.uint8),
        borderType=cv2.BORDER_CONSTANT,
        borderValue=0,
    ).astype(bool)
    if not inner.any():
        raise CalibrationError("a plane's composite frame shows no fringes away from its edges")
    # FTP reads the frame whole: where the projector's light ends inside the view, the step to the unlit
    # pixels spread over the coarse code's lobe (1.8 rad RMS off with a 170 mm projector field; 0.003 with the
    # untrusted pixels set to the trusted ones' mean)
    composite = np.where(valid, composite, np.mean(composite, where=valid))
    rows = []
    # the carrier's phase gradient (along a row, down a column): which of each code's mirrored lobes to read
    rising = (
        np.median(np.diff(phase, axis=1)[valid[:, 1:] & valid[:, :-1]]),
        np.median(np.diff(phase, axis=0)[valid[1:] & valid[:-1]]),
    )
    codes = ftp_code_phases(composite, code_lobe_centres(composite, len(COMPOSITE_CODES), rising))
    for (orders, _), code in zip(COMPOSITE_CODES, codes):
        wrapped = np.mod(code - phase / orders, TWO_PI)
        rows.append(np.where(inner, unwrap_spatial(np.where(inner, wrapped, continued(wrapped, inner))), np.nan))
    return rows


def continued(wrapped: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """A plane's wrapped row phase continued from the pixels inner into the rest, as the linear ramp
    whose gradient is the median of inner's wrapped differences: outside them the phases are noise,
    whose 2 pi jumps would spread through the unwrapping. (Each pixel's nearest inner pixel's phase left
    jumps where the nearest switched, across a rolled camera's wide unlit corners: at 5 degrees the
    fine code unwrapped 40% of a plane a turn or more off, and the calibration was refused.)"""
    v, u = np.mgrid[: wrapped.shape[0], : wrapped.shape[1]]
    steps = (
        wrap_phase(np.diff(wrapped, axis=1))[inner[:, 1:] & inner[:, :-1]],
        wrap_phase(np.diff(wrapped, axis=0))[inner[1:, :] & inner[:-1, :]],
    )
    gx, gy = (np.median(d) if d.size else 0.0 for d in steps)  # no two inner neighbours: a flat fill
    ramp = gx * u + gy * v
    offset = np.angle(np.mean(np.exp(1j * (wrapped - ramp)[inner])))
    return np.mod(ramp + offset, TWO_PI)


def simulated_calibration(
    rig: Rig, patterns: PatternSet, seed: int = 0, depths_mm=CALIBRATION_DEPTHS_MM, working_range_mm=SURFACE_DEPTH_MM
) -> tuple[Calibration, list[float]]:
    """Calibrate the simulated rig the way a user calibrates a real one: render noisy planes, fit.
    The working range defaults to where the simulated scenes put surfaces."""
    rng = np.random.default_rng(seed)
    stacks = [render(rig, plane_scene(rig, z), patterns, rng).images for z in depths_mm]
    return calibrate_from_planes(stacks, list(depths_mm), rig.camera(), patterns, working_range_mm=working_range_mm)


@dataclass
class SceneResult:
    scene: str
    errors: DepthErrors
    noise_limited_rmse_mm: float


def fringe_depth_mm(calibration: Calibration, phase: np.ndarray) -> np.ndarray:
    """Depth spanned by one fringe period of the highest frequency at every pixel."""
    u, v = calibration.camera.ideal_pixels()
    return np.abs(calibration.model.depth_per_radian(phase, u, v)) * 2.0 * np.pi


def wrong_order_mm(calibration: Calibration) -> float:
    """Half the depth one fringe order spans (the median over the image) at the near end of the working
    range (the reference depth where it has none): an error beyond it is a wrong order."""
    cam = calibration.camera
    near = calibration.working_range_mm[0] if calibration.working_range_mm else calibration.reference_depth_mm
    u, v = cam.ideal_pixels()
    phase = np.broadcast_to(calibration.model.phase_at_depth(near, u, v), cam.shape)
    return float(np.median(fringe_depth_mm(calibration, phase))) / 2


def score(
    rec: Reconstruction, truth_depth, truth_valid, calibration: Calibration, noise_sigma: float, name: str
) -> SceneResult:
    """Errors against ground truth, and the RMSE that camera noise alone causes in a phase-shifting
    reconstruction with this modulation (metrics.noise_limited_depth_std, with the camera's rounding
    adding 1/12 count^2 of variance to noise_sigma^2)."""
    errors = depth_errors(rec.depth_mm, truth_depth, truth_valid, fringe_depth_mm(calibration, rec.phase))
    u, v = calibration.camera.ideal_pixels()
    mask = np.isfinite(rec.depth_mm) & truth_valid & (rec.modulation > 0)
    std = noise_limited_depth_std(
        rec.modulation[mask],
        calibration.model.depth_per_radian(rec.phase, u, v)[mask],
        calibration.patterns.steps,
        np.sqrt(noise_sigma**2 + 1.0 / 12.0),
    )
    return SceneResult(name, errors, float(np.sqrt(np.mean(std**2))) if std.size else float("nan"))


def held_out_scenes(rig: Rig, count: int, first_seed: int = 1000):
    """Scenes no calibration or training ever sees: alternately one sculpture and separated objects."""
    for i in range(count):
        kind = ("sculpture", "objects")[i % 2]
        seed = first_seed + i
        yield f"{kind}-{seed}", make_scene(rig, kind, seed), seed
