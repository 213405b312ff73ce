"""A simulated fringe-projection rig (pinhole camera, pinhole projector) and its renderer.

The camera sits at the origin of its optical frame (x right, y down, z forward, millimetres). The
projector sits baseline_mm to its right and aims at the point standoff_mm straight ahead. A scene is
the depth the camera sees at every pixel (a depth map is a solid: what lies behind it is matter), so
the ground truth is exact by construction. A pixel's fringe phase is the projector phase of the
surface point it sees; points the projector cannot reach are in shadow and get ambient light only.

The scenes it renders are in scenes.py. Ambient light, gain, noise and defocus vary per training
scene (random_rig).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import cv2
import numpy as np

from .calibration import CameraIntrinsics, RationalModel
from .patterns import PatternSet, pattern_images


class SimulationError(ValueError):
    """A rig, scene or scene file that cannot be rendered."""


@dataclass(frozen=True)
class Rig:
    """Defaults after the paper: 640x480 camera seeing about 155 mm at about 1.2 m."""

    width: int = 640
    height: int = 480
    focal_px: float = 4955.0  # 640 px over 155 mm at 1200 mm
    standoff_mm: float = 1200.0
    baseline_mm: float = 200.0
    projector_width: int = 1280
    projector_height: int = 800
    projector_field_mm: float = 220.0  # width of the lit area at the standoff
    projector_gamma: float = 2.2
    ambient: float = 0.04  # fraction of the camera's full scale
    gain: float = 0.8  # camera level of full projector light on albedo 1, fraction of full scale
    noise_sigma: float = 1.0  # camera noise standard deviation, in camera counts
    blur_sigma_px: float = 0.5  # defocus, Gaussian standard deviation in camera pixels
    camera_bit_depth: int = 8
    distortion: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)  # the camera lens's k1, k2, p1, p2, k3 (OpenCV's model)
    # a projector not quite beside the camera: down the camera's y axis (negative: above it), and turned about its
    # own axis (its rows against the baseline); both move the rows a camera pixel sees with depth
    projector_below_mm: float = 0.0
    projector_roll_deg: float = 0.0

    def __post_init__(self):
        if self.width < 8 or self.height < 8:
            raise SimulationError(f"camera must be at least 8x8 pixels, got {self.width}x{self.height}")
        for name in ("focal_px", "standoff_mm", "projector_field_mm", "projector_gamma"):
            if not getattr(self, name) > 0:
                raise SimulationError(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("ambient", "gain", "noise_sigma", "blur_sigma_px"):
            if not getattr(self, name) >= 0:
                raise SimulationError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.camera_bit_depth not in (8, 16):
            raise SimulationError(f"camera_bit_depth must be 8 or 16, got {self.camera_bit_depth}")

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def full_scale(self) -> int:
        return (1 << self.camera_bit_depth) - 1

    def camera(self) -> CameraIntrinsics:
        return CameraIntrinsics(
            self.width,
            self.height,
            self.focal_px,
            self.focal_px,
            (self.width - 1) / 2.0,
            (self.height - 1) / 2.0,
            self.distortion,
        )

    def pattern_set(self, **kwargs) -> PatternSet:
        """The default pattern set for this projector (overrides as keyword arguments)."""
        kwargs.setdefault("gamma", self.projector_gamma)
        return PatternSet(width=self.projector_width, height=self.projector_height, **kwargs)

    @property
    def projector_center(self) -> np.ndarray:
        return np.array([self.baseline_mm, self.projector_below_mm, 0.0])

    def projector_rotation(self) -> np.ndarray:
        """Rows are the projector's x, y, z axes in camera coordinates (z towards the aim point; x level,
        then turned by projector_roll_deg about z)."""
        z = np.array([0.0, 0.0, self.standoff_mm]) - self.projector_center
        z /= np.linalg.norm(z)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        a = np.radians(self.projector_roll_deg)
        roll = np.array([[np.cos(a), np.sin(a), 0.0], [-np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        return roll @ np.stack([x, np.cross(z, x), z])

    def projector_intrinsics(self) -> tuple[float, float, float]:
        """(focal, cx, cy) of the projector in projector pixels."""
        distance = np.hypot(np.hypot(self.baseline_mm, self.projector_below_mm), self.standoff_mm)  # to the aim point
        focal = self.projector_width * distance / self.projector_field_mm
        return focal, (self.projector_width - 1) / 2.0, (self.projector_height - 1) / 2.0

    def to_projector(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Projector pixel coordinates (x, y) and depth in the projector frame of (..., 3) points."""
        r = self.projector_rotation()
        q = (points - self.projector_center) @ r.T
        focal, cx, cy = self.projector_intrinsics()
        return focal * q[..., 0] / q[..., 2] + cx, focal * q[..., 1] / q[..., 2] + cy, q[..., 2]

    def true_model(self, patterns: PatternSet) -> RationalModel:
        """The rational model this rig obeys, derived from its geometry, in the camera's ideal pixel
        coordinates (CameraIntrinsics.ideal_pixels: exact with lens distortion too).

        A camera ray Z (x, y, 1) lands on projector coordinate
        s = f (Z a_r + t_r) / (Z a_3 + t_3) + c_r, and phase = k s with k = 2 pi f_max / L, so
        Z = (f t_r + c_r t_3 - (t_3 / k) phase) / ((phase / k - c_r) a_3 - f a_r)
        with a_r, a_3 linear in (u, v): the first six terms of equation (3), the rest zero.
        """
        check_patterns(self, patterns)
        axis = 0 if patterns.orientation == "vertical" else 1
        r = self.projector_rotation()
        t = -r @ self.projector_center
        focal, cx_p, cy_p = self.projector_intrinsics()
        c_r = (cx_p, cy_p)[axis]
        k = 2.0 * np.pi * patterns.frequencies[-1] / patterns.period_axis_length
        cam = self.camera()

        def linear(row):  # row . ((u - cx)/fx, (v - cy)/fy, 1) = const + du u + dv v
            return (row[2] - row[0] * cam.cx / cam.fx - row[1] * cam.cy / cam.fy, row[0] / cam.fx, row[1] / cam.fy)

        alpha, beta = linear(r[axis]), linear(r[2])
        c = np.zeros(12)
        d = np.zeros(12)
        c[0], c[1] = focal * t[axis] + c_r * t[2], -t[2] / k
        for i in range(3):  # terms 1, u, v and their phase partners
            d[2 * i] = -c_r * beta[i] - focal * alpha[i]
            d[2 * i + 1] = beta[i] / k
        return RationalModel(c / c[0], d / c[0])


def check_patterns(rig: Rig, patterns: PatternSet) -> None:
    if (patterns.width, patterns.height) != (rig.projector_width, rig.projector_height):
        raise SimulationError(
            f"pattern set is {patterns.width}x{patterns.height} but the projector is "
            f"{rig.projector_width}x{rig.projector_height}"
        )


@dataclass
class Scene:
    name: str
    depth_mm: np.ndarray  # (H, W) depth along the camera axis of the surface each pixel sees
    albedo: np.ndarray  # (H, W) in [0, 1]


@dataclass
class Capture:
    images: np.ndarray  # (F*N, H, W) uint8/uint16 in projection order
    depth_mm: np.ndarray  # (H, W) float64 ground truth
    valid: np.ndarray  # (H, W) bool: a surface (albedo > 0) lit by the projector (not in shadow, inside its frame)
    projector_coord: np.ndarray  # (H, W) exact projector coordinate across the fringes


# Per-scene photometry (random_rig)
AMBIENT = (0.0, 0.15)
GAIN = (0.4, 1.0)
NOISE_SIGMA = (0.5, 3.0)
BLUR_SIGMA_PX = (0.3, 1.2)


def random_rig(rng: np.random.Generator, base: Rig) -> Rig:
    """The base rig with per-scene photometry: ambient, gain, noise and defocus drawn uniformly."""
    # projector_gamma stays the base's: the patterns are pre-compensated for the rig's gamma, and a
    # different gamma would need a matching pattern set.
    return replace(
        base,
        ambient=rng.uniform(*AMBIENT),
        gain=rng.uniform(*GAIN),
        noise_sigma=rng.uniform(*NOISE_SIGMA),
        blur_sigma_px=rng.uniform(*BLUR_SIGMA_PX),
    )


# Photometry beyond those ranges (export's hard validation scenes): each setting's ranges, one drawn
BEYOND_TRAINING = {
    "ambient": ((0.15, 0.35),),
    "gain": ((0.15, 0.4), (1.0, 1.4)),
    "noise_sigma": ((3.0, 6.0),),
    "blur_sigma_px": ((1.2, 3.5),),
    "projector_gamma": ((1.7, 2.0), (2.4, 2.7)),  # the patterns stay pre-compensated for the base rig's (2.2)
}


def beyond_training_rig(rng: np.random.Generator, base: Rig) -> tuple[Rig, str]:
    """random_rig with one or two of its settings drawn beyond the training ranges (BEYOND_TRAINING), and
    what they are, e.g. 'gain 0.23, blur_sigma_px 2.71'."""
    rig = random_rig(rng, base)
    names = rng.choice(sorted(BEYOND_TRAINING), size=int(rng.integers(1, 3)), replace=False)
    changes = {}
    for name in names:
        ranges = BEYOND_TRAINING[name]
        changes[str(name)] = float(rng.uniform(*ranges[int(rng.integers(len(ranges)))]))
    return replace(rig, **changes), ", ".join(f"{name} {value:.2f}" for name, value in changes.items())


# ---------------------------------------------------------------- rendering


def projector_shadow(
    rig: Rig,
    depth: np.ndarray,
    cam: CameraIntrinsics,
    step_px: float = 0.5,
    tolerance_mm: float = 0.1,
    needed: np.ndarray | None = None,
) -> np.ndarray:
    """Pixels whose surface point cannot see the projector.

    March from each point towards the projector centre until the ray is nearer than the nearest
    surface; the point is shadowed if a sample lies behind the surface the camera sees there.
    The march is fine enough (step_px) for the pixels in needed (default all); others, such as a
    black void far behind the scene, are marched more coarsely.
    """
    x, y = cam.rays()
    points = np.stack([x * depth, y * depth, depth], axis=-1)
    to_projector = rig.projector_center - points
    t_max = (depth - depth.min()) / (depth - rig.projector_center[2])
    far = points + t_max[..., None] * to_projector
    reach_px = cam.fx * np.abs(far[..., 0] / far[..., 2] - x)
    if needed is None or not needed.any():
        needed = np.ones(depth.shape, bool)
    steps = int(np.ceil(reach_px[needed].max() / step_px))
    surface = depth.astype(np.float32)
    shadow = np.zeros(depth.shape, bool)
    for s in np.arange(1, steps + 1) / max(steps, 1):
        q = points + (s * t_max)[..., None] * to_projector
        uq, vq = (c.astype(np.float32) for c in cam.project(q))
        seen = cv2.remap(surface, uq, vq, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.inf)
        moved = reach_px * s >= 1.0  # samples within a pixel of the point see the point itself
        shadow |= moved & (q[..., 2] > seen + tolerance_mm)
    return shadow


class Bilinear:
    """Sampling images of one size at fixed fractional pixel coordinates (x, y), linear between pixel
    centres, the border extended: the indices and weights are worked out once (cv2.remap rounds the
    fractions to 1/32 pixel, a 0.008 rad phase error at the carrier)."""

    def __init__(self, shape: tuple[int, int], x: np.ndarray, y: np.ndarray):
        h, w = shape
        x = np.clip(x, 0, w - 1)
        y = np.clip(y, 0, h - 1)
        x0 = np.minimum(np.floor(x).astype(np.intp), w - 2)
        y0 = np.minimum(np.floor(y).astype(np.intp), h - 2)
        self.index = y0 * w + x0
        self.fx, self.fy, self.w = x - x0, y - y0, w

    def __call__(self, image: np.ndarray) -> np.ndarray:
        flat, i, fx = image.ravel(), self.index, self.fx
        top = flat[i] * (1 - fx) + flat[i + 1] * fx
        bottom = flat[i + self.w] * (1 - fx) + flat[i + self.w + 1] * fx
        return top * (1 - self.fy) + bottom * self.fy


class SceneRenderer:
    """One scene under the rig: the geometry (where each pixel's surface point lands in the projector,
    whether the projector reaches it) is computed once, then image() renders any pattern shown.

    Camera level = full_scale * (ambient + gain * albedo * (pattern / max) ** projector_gamma), then
    defocus blur, Gaussian noise (noise_sigma counts; skipped when rng is None), rounding and clipping.
    The projector is pixelated: the pattern is interpolated linearly between its pixel centres.
    """

    def __init__(self, rig: Rig, scene: Scene):
        depth = np.asarray(scene.depth_mm, np.float64)
        if depth.shape != (rig.height, rig.width):
            raise SimulationError(
                f"scene is {depth.shape[1]}x{depth.shape[0]} but the camera is {rig.width}x{rig.height}"
            )
        self.rig, self.scene = rig, scene
        # Render a margin beyond the image (the scene's border extended) so that the blur near the
        # border mixes in what a real lens would, not a mirror image of the fringes.
        m = int(np.ceil(4 * rig.blur_sigma_px))
        cam = rig.camera()
        canvas = replace(cam, width=cam.width + 2 * m, height=cam.height + 2 * m, cx=cam.cx + m, cy=cam.cy + m)
        depth = cv2.copyMakeBorder(depth, m, m, m, m, cv2.BORDER_REPLICATE)
        albedo = cv2.copyMakeBorder(np.asarray(scene.albedo, np.float64), m, m, m, m, cv2.BORDER_REPLICATE)
        x, y = canvas.rays()
        self.xp, self.yp, zp = rig.to_projector(np.stack([x * depth, y * depth, depth], axis=-1))
        inside = (
            (zp > 0)
            & (self.xp >= -0.5)
            & (self.xp <= rig.projector_width - 0.5)
            & (self.yp >= -0.5)
            & (self.yp <= rig.projector_height - 0.5)
        )
        surface = albedo > 0  # albedo 0 is a void (no surface in range): never valid, no shadow needed
        self.lit = inside & surface & ~projector_shadow(rig, depth, canvas, needed=surface)
        self.reflect = (rig.full_scale * rig.gain * albedo * self.lit).astype(np.float32)
        self.crop = (slice(m, m + rig.height), slice(m, m + rig.width))
        self._bilinear = None  # for full pattern images, made on first use

    @property
    def projector_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """Where each camera pixel's surface point lands in the projector (its pixels), without the margin."""
        return self.xp[self.crop], self.yp[self.crop]

    def image(self, pattern: np.ndarray, max_value: int, rng: np.random.Generator | None = None) -> np.ndarray:
        """What the camera captures while the projector shows this pattern: a 1 x W line (vertical
        fringes), an H x 1 line (horizontal) or a full H x W image, as patterns.pattern_images gives."""
        rig = self.rig
        pattern = np.asarray(pattern, np.float64) / max_value
        if pattern.shape[0] == 1 or pattern.shape[1] == 1:
            coord = self.xp if pattern.shape[0] == 1 else self.yp
            light = np.interp(coord, np.arange(pattern.size), pattern.reshape(-1)).astype(np.float32)
        else:
            if self._bilinear is None:
                self._bilinear = Bilinear(pattern.shape, self.xp, self.yp)
            light = self._bilinear(pattern).astype(np.float32)
        level = cv2.pow(light, rig.projector_gamma)
        level *= self.reflect
        level += rig.full_scale * rig.ambient
        if rig.blur_sigma_px > 0:
            level = cv2.GaussianBlur(level, (0, 0), rig.blur_sigma_px)
        level = level[self.crop]
        if rng is not None and rig.noise_sigma > 0:
            level = level + rig.noise_sigma * rng.standard_normal(level.shape, dtype=np.float32)
        dtype = np.uint8 if rig.camera_bit_depth == 8 else np.uint16
        return np.clip(np.rint(level), 0, rig.full_scale).astype(dtype)

    def truth(self, vertical: bool = True) -> Capture:
        """Ground truth without images: depth, lit mask, exact projector coordinate."""
        coord = self.xp if vertical else self.yp
        return Capture(
            np.empty((0, self.rig.height, self.rig.width), np.uint8),
            np.asarray(self.scene.depth_mm, np.float64),
            self.lit[self.crop],
            coord[self.crop],
        )


def render(rig: Rig, scene: Scene, patterns: PatternSet, rng: np.random.Generator | None = None) -> Capture:
    """The images the camera captures of the scene under each pattern, with the exact ground truth."""
    check_patterns(rig, patterns)
    renderer = SceneRenderer(rig, scene)
    vertical = patterns.orientation == "vertical"
    capture = renderer.truth(vertical)
    capture.images = np.stack([renderer.image(image, patterns.max_value, rng) for image in pattern_images(patterns)])
    return capture


def render_pose(rig: Rig, scene: Scene, pattern_sets: list, rng: np.random.Generator | None = None):
    """A calibration pose: the scene under full projector light, then its images under each pattern set."""
    renderer = SceneRenderer(rig, scene)
    white = np.full((1, rig.projector_width), 255, np.uint8)
    stacks = []
    for patterns in pattern_sets:
        check_patterns(rig, patterns)
        stacks.append(np.stack([renderer.image(image, patterns.max_value, rng) for image in pattern_images(patterns)]))
    return renderer.image(white, 255, rng), stacks
