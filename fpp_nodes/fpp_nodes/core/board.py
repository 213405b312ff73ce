"""Calibrating a rig from a printed checkerboard at free poses, the projector as an inverse camera
(after Zhang 2000 for the camera and Moreno and Taubin 2012 for the projector).

Each pose gives an image in which the board is seen and two fringe sets, vertical and horizontal
fringes. OpenCV finds the board's corners and calibrates the camera (intrinsics and lens distortion);
the corners are found again on the board seen square-on through that calibration, and it is redone.
The two unwrapped phases give every lit pixel its projector coordinates; a homography fitted to the
pixels around each corner (robustly: the checker's edges blur the phase) carries the corner into the
projector, which is then calibrated like a camera, and stereo calibration gives its pose. The
phase-to-depth model is fitted to that geometry: virtual planes across the measured depths, each
pixel's ray meeting them, each meeting point's projector coordinate turned into the phase it sees.
The model is written in the camera's ideal pixel coordinates (CameraIntrinsics.ideal_pixels), so
the camera's distortion does not bend it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from .calibration import Calibration, CalibrationError, CameraIntrinsics, fit_rational_model
from .patterns import PatternSet
from .phase import TWO_PI
from .reconstruct import multi_frequency_phase

MIN_POSES = 4  # Zhang's method needs three views; a fourth leaves the fit some redundancy
MIN_TILT_SPREAD_DEG = 5.0  # poses whose boards all face the same way leave the focal length free
CORNER_WINDOW_PX = 20  # half-width of the pixel window around a corner that the local homography fits
MAX_PHASE_NOISE_RAD = 0.05  # pixels the homography uses (as the plane calibration's)
VIRTUAL_PLANES = 7
CORNER_REFINEMENTS = 2  # rounds of square_on_corners and recalibration
SQUARE_ON_PX = 40  # a square's side in the square-on view of the board
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)  # cornerSubPix's stop
# Lens models the fit may use (OpenCV flags). Radial k1 alone is the default: more terms bought nothing
# the poses could tell (scripts/board_vs_plane.py, one draw: 0.14, 0.12 and 0.13 mm at 7 degrees of
# field, 0.20, 0.21 and 0.28 mm at 24 degrees, planes flat to 1.0-1.3x their noise); lenses with
# more than barrel distortion want more.
LENS_MODELS = {
    "k1": cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "k1k2": cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "full": cv2.CALIB_FIX_K3,
}
DEPTH_MARGIN_MM = 100.0  # the model covers the boards' depths and this much either side
# a pose whose corners the calibrated projector puts further than this from where its fringes put them (RMS, px)
# is refused: the simulated rigs' poses give at most 0.3 px, a mirrored projector read as a pinhole gave 8-41 px
MAX_PROJECTOR_PX = 2.0


@dataclass(frozen=True)
class Board:
    """A checkerboard: inner corners across and down (OpenCV's pattern size), square side in mm."""

    cols: int
    rows: int
    square_mm: float

    @classmethod
    def parse(cls, spec: str) -> Board:
        """'COLSxROWS:SQUARE_MM', e.g. '8x6:10' (inner corners)."""
        try:
            size, square = spec.split(":")
            cols, rows = (int(n) for n in size.lower().split("x"))
            board = cls(cols, rows, float(square))
        except ValueError:
            raise CalibrationError(
                f"board {spec!r} must be COLSxROWS:SQUARE_MM (inner corners, mm), e.g. 8x6:10"
            ) from None
        if min(cols, rows) < 3 or cols == rows or not board.square_mm > 0:
            raise CalibrationError(
                f"board {spec!r}: at least 3x3 inner corners, unequal counts (so its orientation is known) "
                "and a positive square size"
            )
        return board

    def object_points(self) -> np.ndarray:
        """The inner corners in the board's frame (mm, z = 0), in OpenCV's order: row by row."""
        x, y = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=-1).astype(np.float32) * self.square_mm

    def albedo(self, bx: np.ndarray, by: np.ndarray, dark: float = 0.3, light: float = 0.9) -> np.ndarray:
        """The printed board at board coordinates (mm; the first inner corner at 0, 0): (cols + 1) x
        (rows + 1) squares of `dark` and `light`, a light margin one square wide, nothing (0) beyond."""
        i, j = np.floor(bx / self.square_mm), np.floor(by / self.square_mm)
        checker = (i >= -1) & (i <= self.cols - 1) & (j >= -1) & (j <= self.rows - 1)
        paper = (i >= -2) & (i <= self.cols) & (j >= -2) & (j <= self.rows)
        return np.where(checker, np.where((i + j) % 2 == 0, dark, light), np.where(paper, light, 0.0))

    def centre(self) -> np.ndarray:
        return np.array([(self.cols - 1) / 2, (self.rows - 1) / 2, 0.0]) * self.square_mm


@dataclass
class BoardPose:
    """One pose of the board: its image under full projector light, and the vertical and horizontal
    fringe sets (each in projection order)."""

    name: str
    image: np.ndarray
    vertical: np.ndarray
    horizontal: np.ndarray


@dataclass
class PoseReport:
    name: str
    depth_mm: float  # the board's distance along the optical axis
    camera_px: float  # RMS reprojection error of the corners in the camera
    projector_px: float  # ... and in the projector
    corners: int  # corners carried into the projector


@dataclass
class BoardReport:
    """What the board calibration found besides the calibration: per pose its errors, the projector
    as an inverse camera, and its pose (x_projector = rotation @ x_camera + translation, mm)."""

    poses: list[PoseReport]
    projector: CameraIntrinsics
    rotation: np.ndarray
    translation_mm: np.ndarray
    model_fit_mm: float  # RMS depth difference of the rational model from exact triangulation, over the virtual planes
    projector_mirrored: bool = False  # it shows its image mirrored (rear mode): its columns read mirrored back


def board_patterns(patterns: PatternSet) -> tuple[PatternSet, PatternSet]:
    """The fringe sets a board pose shows, vertical then horizontal fringes (the projector's columns, then
    its rows): the calibration's own set (with its single-shot frame) for its fringes' way, and the same
    frequencies and steps the other way, without it."""
    vertical = patterns.orientation == "vertical"
    crossed = replace(patterns, orientation="horizontal" if vertical else "vertical", single_shot="paper")
    return (patterns, crossed) if vertical else (crossed, patterns)


def find_corners(image: np.ndarray, board: Board) -> np.ndarray | None:
    """The board's inner corners (N x 2, float32, subpixel), or None where the board is not found."""
    grey = image if image.dtype == np.uint8 else cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
    found, corners = cv2.findChessboardCorners(
        grey, (board.cols, board.rows), flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if not found:
        return None
    return cv2.cornerSubPix(grey, corners, (7, 7), (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2)


def square_on_corners(image, board: Board, k: np.ndarray, d: np.ndarray, rvec, tvec) -> np.ndarray:
    """The corners found again on the board seen square-on (after Datta, Kim and Kanade 2009): the
    image resampled onto the board's plane through the current calibration, where neither the lens
    nor the perspective bends the checker, the corners refined there and carried back into the image.
    On a tilted board cornerSubPix's corners are biased, and the focal length with them."""
    scale = SQUARE_ON_PX / board.square_mm  # pixels per mm of the square-on view
    s = board.square_mm
    bx, by = np.meshgrid(
        np.arange(int((board.cols + 1) * s * scale)) / scale - s,
        np.arange(int((board.rows + 1) * s * scale)) / scale - s,
    )
    points = np.stack([bx.ravel(), by.ravel(), np.zeros(bx.size)], axis=-1)
    uv = cv2.projectPoints(points, rvec, tvec, k, d)[0].reshape(*bx.shape, 2).astype(np.float32)
    square_on = cv2.remap(np.asarray(image, np.float32), uv[..., 0], uv[..., 1], cv2.INTER_LINEAR)
    start = ((board.object_points()[:, :2] + s) * scale).reshape(-1, 1, 2).astype(np.float32)
    window = int(0.3 * SQUARE_ON_PX)
    refined = cv2.cornerSubPix(square_on, start, (window, window), (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2) / scale - s
    on_board = np.c_[refined, np.zeros(len(refined))]
    return cv2.projectPoints(on_board, rvec, tvec, k, d)[0].reshape(-1, 2).astype(np.float32)


def projector_coordinates(pose: BoardPose, patterns: PatternSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pixel's projector column and row (from the vertical and horizontal fringes' unwrapped
    phases: phase = 2 pi f_max s / L) and where both are trustworthy."""
    out, ok = [], None
    for images, p in zip((pose.vertical, pose.horizontal), board_patterns(patterns)):
        phase, valid, _, noise, _ = multi_frequency_phase(np.asarray(images), p)
        valid &= noise <= MAX_PHASE_NOISE_RAD
        ok = valid if ok is None else ok & valid
        out.append(phase.astype(np.float64) * p.period_axis_length / (TWO_PI * p.frequencies[-1]))
    return out[0], out[1], ok


def corners_in_projector(corners: np.ndarray, xp: np.ndarray, yp: np.ndarray, ok: np.ndarray):
    """Each corner's projector coordinates by a local homography (camera -> projector) fitted, with
    least median of squares, to the trusted pixels within CORNER_WINDOW_PX; NaN where too few."""
    h, w = ok.shape
    out = np.full(corners.shape, np.nan)
    r = CORNER_WINDOW_PX
    for k, (cu, cv) in enumerate(corners):
        u0, u1 = max(int(cu) - r, 0), min(int(cu) + r + 1, w)
        v0, v1 = max(int(cv) - r, 0), min(int(cv) + r + 1, h)
        v, u = np.nonzero(ok[v0:v1, u0:u1])
        if u.size < (r + 1) ** 2:  # under a quarter of the window
            continue
        u, v = u + u0, v + v0
        src = np.stack([u, v], axis=-1).astype(np.float64)
        dst = np.stack([xp[v, u], yp[v, u]], axis=-1)
        homography, _ = cv2.findHomography(src, dst, cv2.LMEDS)
        if homography is not None:
            out[k] = cv2.perspectiveTransform(corners[k].reshape(1, 1, 2).astype(np.float64), homography).ravel()
    return out


def _board_poses(objects, points, k, d):
    """Each board's pose in the camera from its corners (after the joint refinement)."""
    poses = [cv2.solvePnP(o, p, k, d, flags=cv2.SOLVEPNP_ITERATIVE)[1:] for o, p in zip(objects, points)]
    return [r for r, _ in poses], [t for _, t in poses]


def _intrinsics(matrix: np.ndarray, distortion: np.ndarray, size: tuple[int, int]) -> CameraIntrinsics:
    """OpenCV's camera matrix and distortion coefficients as ours."""
    fx, fy, cx, cy = (float(matrix[i, j]) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    return CameraIntrinsics(size[0], size[1], fx, fy, cx, cy, tuple(distortion.ravel()[:5]))


def _rms(errors) -> float:
    return float(np.sqrt(np.mean(np.sum(np.square(errors), axis=-1))))


def calibrate_from_board(
    poses: list[BoardPose],
    board: Board,
    patterns: PatternSet,
    reference_depth_mm: float | None = None,
    lens: str = "k1",
    working_range_mm: tuple[float, float] | None = None,
) -> tuple[Calibration, BoardReport]:
    """The rig's calibration from board poses, and what else it found (BoardReport). lens: which
    distortion terms camera and projector get (LENS_MODELS); the working range is the boards' depths
    (at their centres) unless given. Clear errors for a pose whose board is not found or not lit, too
    few poses, and poses that all face one way."""
    if lens not in LENS_MODELS:
        raise CalibrationError(f"lens model {lens!r} is not one of {', '.join(LENS_MODELS)}")
    if len(poses) < MIN_POSES:
        raise CalibrationError(
            f"{len(poses)} board poses; board calibration needs at least {MIN_POSES} "
            "(15 tilted by up to 45 deg work well)"
        )
    shape = np.asarray(poses[0].image).shape
    found, maps = [], []
    for pose in poses:
        if np.asarray(pose.image).shape != shape:
            raise CalibrationError(f"pose {pose.name}: its image is {pose.image.shape}, the first pose's {shape}")
        corners = find_corners(np.asarray(pose.image), board)
        if corners is None:
            raise CalibrationError(
                f"pose {pose.name}: the board ({board.cols}x{board.rows} inner corners) is not found in its image"
            )
        found.append(corners)
        maps.append(projector_coordinates(pose, patterns))
    flags = LENS_MODELS[lens]
    size = (shape[1], shape[0])
    everything = [board.object_points()] * len(poses)
    _, k_cam, d_cam, rvecs, tvecs = cv2.calibrateCamera(everything, found, size, None, None, flags=flags)
    normals = np.array([cv2.Rodrigues(r)[0][:, 2] for r in rvecs])
    spread = np.degrees(np.arccos(np.clip(np.min(normals @ normals.T), -1, 1)))
    if spread < MIN_TILT_SPREAD_DEG:
        raise CalibrationError(
            f"the {len(poses)} poses' boards face the same way (within {spread:.1f} deg): they do not tell the "
            f"focal length; tilt the board 20-45 deg in different directions"
        )
    for _ in range(CORNER_REFINEMENTS):
        found = [square_on_corners(p.image, board, k_cam, d_cam, r, t) for p, r, t in zip(poses, rvecs, tvecs)]
        _, k_cam, d_cam, rvecs, tvecs = cv2.calibrateCamera(everything, found, size, k_cam, d_cam, flags=flags)
    objects, camera_points, projector_points = [], [], []
    for pose, corners, pose_maps in zip(poses, found, maps):
        projected = corners_in_projector(corners, *pose_maps)
        seen = np.isfinite(projected).all(axis=-1)
        if seen.sum() < 0.5 * len(corners):
            raise CalibrationError(
                f"pose {pose.name}: only {seen.sum()} of {len(corners)} corners are lit by decodable fringes "
                "(is the board inside the projector's light, and the exposure right?)"
            )
        objects.append(board.object_points()[seen])
        camera_points.append(corners[seen].astype(np.float32))
        projector_points.append(projected[seen].astype(np.float32))
    # a projector showing its image mirrored (rear mode) is no pinhole: its columns are read mirrored back, and
    # mirrored again in the model (ceiling mode mirrors both ways: a half turn, which the pose takes up)
    mirrored = projector_mirrored(objects, camera_points, projector_points)
    if mirrored:
        for points in projector_points:
            points[:, 0] = patterns.width - 1 - points[:, 0]
    projector_size = (patterns.width, patterns.height)
    _, k_proj, d_proj, *_ = cv2.calibrateCamera(objects, projector_points, projector_size, None, None, flags=flags)
    _, k_cam, d_cam, k_proj, d_proj, rotation, translation, *_ = cv2.stereoCalibrate(
        objects,
        camera_points,
        projector_points,
        k_cam,
        d_cam,
        k_proj,
        d_proj,
        size,
        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
    )
    rvecs, tvecs = _board_poses(objects, camera_points, k_cam, d_cam)
    camera = _intrinsics(k_cam, d_cam, size)
    reports = []
    for i, pose in enumerate(poses):
        cam_err = cv2.projectPoints(objects[i], rvecs[i], tvecs[i], k_cam, d_cam)[0].reshape(-1, 2) - camera_points[i]
        r_proj = cv2.Rodrigues(rotation @ cv2.Rodrigues(rvecs[i])[0])[0]
        t_proj = rotation @ tvecs[i] + translation
        proj = cv2.projectPoints(objects[i], r_proj, t_proj, k_proj, d_proj)[0].reshape(-1, 2)
        depth = float((cv2.Rodrigues(rvecs[i])[0] @ board.centre() + tvecs[i].ravel())[2])
        reports.append(PoseReport(pose.name, depth, _rms(cam_err), _rms(proj - projector_points[i]), len(objects[i])))
    worst = max(reports, key=lambda r: r.projector_px)
    if worst.projector_px > MAX_PROJECTOR_PX:
        raise CalibrationError(
            f"pose {worst.name}: the calibrated projector puts its corners {worst.projector_px:.1f} px RMS from where "
            f"its fringes put them (at most {MAX_PROJECTOR_PX:g}): are the poses' fringe sets the pattern set's, in "
            "order, and is the projector's image shown unscaled?"
        )
    depths = [r.depth_mm for r in reports]
    model, code_models, fit_mm = model_from_geometry(
        camera, patterns, rotation, translation, k_proj, d_proj, (min(depths), max(depths)), mirrored
    )
    reference = float(np.median(depths)) if reference_depth_mm is None else float(reference_depth_mm)
    projector = _intrinsics(k_proj, d_proj, projector_size)
    report = BoardReport(reports, projector, rotation, translation.ravel(), fit_mm, mirrored)
    working_range = working_range_mm or (min(depths), max(depths))
    return Calibration(camera, model, patterns, reference, code_models, working_range), report


def projector_mirrored(objects, camera_points, projector_points) -> bool:
    """Whether the projector shows its image mirrored: the boards' corners (objects, on each board) turn
    the other way in it than in the camera (in most poses), which no pinhole does."""

    def turn(board, points):  # +1 or -1: which way the board's x axis turns onto its y axis in points
        homography, _ = cv2.findHomography(board[:, :2].astype(np.float64), points.astype(np.float64))
        centre = board[:, :2].mean(axis=0)
        corner = np.array([[centre, centre + (1, 0), centre + (0, 1)]], np.float64)
        a, b, c = cv2.perspectiveTransform(corner, homography)[0]
        return np.sign((b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0])

    turns = [turn(o, c) * turn(o, p) for o, c, p in zip(objects, camera_points, projector_points)]
    return bool(np.median(turns) < 0)


def model_from_geometry(
    camera, patterns, rotation, translation, k_proj, d_proj, depth_range_mm, mirrored: bool = False, step: int = 4
):
    """The rational phase-to-depth model (and, with the composite pattern, its code models; and the
    model's RMS depth difference from exact triangulation over the samples) fitted to
    virtual planes square to the camera across depth_range_mm widened by DEPTH_MARGIN_MM: each
    sampled pixel's ray meets each plane, the projector (rotation, translation from the camera's
    frame; intrinsics, distortion) sees the meeting point at (xp, yp), the carrier's phase there is
    2 pi f_max xp / W and each code's row phase 2 pi fy yp / H (patterns.composite_phases; yp and xp for
    horizontal fringes); xp mirrored (W - 1 - xp) where the projector shows its image mirrored."""
    x, y = (a[::step, ::step].ravel() for a in camera.rays())
    u, v = (np.broadcast_to(a, camera.shape)[::step, ::step].ravel() for a in camera.ideal_pixels())
    near, far = depth_range_mm[0] - DEPTH_MARGIN_MM, depth_range_mm[1] + DEPTH_MARGIN_MM
    samples = []
    for z in np.linspace(near, far, VIRTUAL_PLANES):
        points = np.stack([x * z, y * z, np.full(x.size, z)], axis=-1)
        xp, yp = cv2.projectPoints(points, cv2.Rodrigues(rotation)[0], translation, k_proj, d_proj)[0].reshape(-1, 2).T
        xp = patterns.width - 1 - xp if mirrored else xp
        lit = (xp >= 0) & (xp <= patterns.width - 1) & (yp >= 0) & (yp <= patterns.height - 1)
        across, along = patterns.across_along(xp, yp)
        phase = TWO_PI * patterns.frequencies[-1] * across
        chi = [TWO_PI * fb * along[lit] + phase[lit] for _, fb in patterns.code_frequencies]
        samples.append((u[lit], v[lit], phase[lit], np.full(lit.sum(), z), *chi))
    if sum(len(s[0]) for s in samples) < 1000:
        raise CalibrationError("the calibrated projector lights almost none of the camera's view: check the poses")
    u, v, phase, depth, *chis = (np.concatenate(parts) for parts in zip(*samples))
    model = fit_rational_model(u, v, phase, depth)
    code_models = [fit_rational_model(u, v, chi, depth) for chi in chis] if patterns.single_shot == "composite" else []
    fit_mm = float(np.sqrt(np.mean((model.depth(phase, u, v) - depth) ** 2)))
    return model, code_models, fit_mm
