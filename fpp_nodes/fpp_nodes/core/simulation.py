"""A simulated fringe-projection rig: pinhole camera, pinhole projector, synthetic scenes.

The camera sits at the origin of its optical frame (x right, y down, z forward, millimetres). The
projector sits baseline_mm to its right and aims at the point standoff_mm straight ahead. A scene is
the depth the camera sees at every pixel (a depth map is a solid: what lies behind it is matter), so
the ground truth is exact by construction. A pixel's fringe phase is the projector phase of the
surface point it sees; points the projector cannot reach are in shadow and get ambient light only.

Training and evaluation scenes come in families (SCENE_FAMILIES: bust, freeform, blocks, spheres,
thin, planes, floating) that cover the working volume: a background plane at 1100-1300 mm depth at
the image centre, tilted by up to 35 degrees in any direction, or no background at all (floating
objects before a black void); objects up to 100 mm tall on it; every surface between 1000 and
1350 mm. Albedo 0.15-1.0, times a texture: smooth, checkers, print, stripes or none, drawn
independently for objects and background. Ambient light, gain, noise and defocus vary per scene
(random_rig).
"""
from __future__ import annotations

from dataclasses import dataclass, asdict, replace
from pathlib import Path

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
        return CameraIntrinsics(self.width, self.height, self.focal_px, self.focal_px,
                                (self.width - 1) / 2.0, (self.height - 1) / 2.0)

    def pattern_set(self, **kwargs) -> PatternSet:
        """The default pattern set for this projector (overrides as keyword arguments)."""
        kwargs.setdefault("gamma", self.projector_gamma)
        return PatternSet(width=self.projector_width, height=self.projector_height, **kwargs)

    @property
    def projector_center(self) -> np.ndarray:
        return np.array([self.baseline_mm, 0.0, 0.0])

    def projector_rotation(self) -> np.ndarray:
        """Rows are the projector's x, y, z axes in camera coordinates (z towards the aim point)."""
        z = np.array([0.0, 0.0, self.standoff_mm]) - self.projector_center
        z /= np.linalg.norm(z)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        return np.stack([x, np.cross(z, x), z])

    def projector_intrinsics(self) -> tuple[float, float, float]:
        """(focal, cx, cy) of the projector in projector pixels."""
        distance = np.hypot(self.baseline_mm, self.standoff_mm)
        focal = self.projector_width * distance / self.projector_field_mm
        return focal, (self.projector_width - 1) / 2.0, (self.projector_height - 1) / 2.0

    def to_projector(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Projector pixel coordinates (x, y) and depth in the projector frame of (..., 3) points."""
        r = self.projector_rotation()
        q = (points - self.projector_center) @ r.T
        focal, cx, cy = self.projector_intrinsics()
        return focal * q[..., 0] / q[..., 2] + cx, focal * q[..., 1] / q[..., 2] + cy, q[..., 2]

    def true_model(self, patterns: PatternSet) -> RationalModel:
        """The rational model this distortion-free rig obeys, derived from its geometry.

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
        raise SimulationError(f"pattern set is {patterns.width}x{patterns.height} but the projector is "
                              f"{rig.projector_width}x{rig.projector_height}")


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


# ---------------------------------------------------------------- scenes

def _grid_mm(rig: Rig):
    """Metric coordinates (X, Y) of every pixel's footprint on the plane at the standoff."""
    x, y = rig.camera().rays()
    return x * rig.standoff_mm, y * rig.standoff_mm


def _background_depth(rig: Rig, tilt_x_deg: float = 0.0, tilt_y_deg: float = 0.0, offset_mm: float = 0.0):
    """Depth of the plane Z = Z0 + X tan(a) + Y tan(b) along every camera ray."""
    x, y = rig.camera().rays()
    return (rig.standoff_mm + offset_mm) / (1.0 - x * np.tan(np.radians(tilt_x_deg)) - y * np.tan(np.radians(tilt_y_deg)))


def _smooth_field(rng, shape, scale_px: float) -> np.ndarray:
    """Random smooth field in [0, 1] with features about scale_px wide."""
    noise = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), scale_px)
    noise -= noise.min()
    return (noise / max(float(noise.max()), 1e-12)).astype(np.float64)


def _albedo(rng, shape, low: float, high: float) -> np.ndarray:
    return low + (high - low) * _smooth_field(rng, shape, 12.0)


def plane_scene(rig: Rig, depth_mm: float, tilt_x_deg: float = 0.0, tilt_y_deg: float = 0.0) -> Scene:
    depth = _background_depth(rig, tilt_x_deg, tilt_y_deg, depth_mm - rig.standoff_mm)
    return Scene(f"plane@{depth_mm:g}mm", depth, np.full(depth.shape, 0.9))


def _ellipsoid(X, Y, cx, cy, a, b, height):
    r2 = ((X - cx) / a) ** 2 + ((Y - cy) / b) ** 2
    return height * np.sqrt(np.clip(1.0 - r2, 0.0, None))


def _bust_height(X, Y, rng: np.random.Generator) -> np.ndarray:
    """Height (mm) of a plaster-bust-like object near the origin: body, head, nose, brows, folds."""
    cx, cy = rng.uniform(-12, 12), rng.uniform(-6, 10)
    body = _ellipsoid(X, Y, cx, cy + 22, rng.uniform(28, 40), rng.uniform(22, 30), rng.uniform(25, 40))
    body += rng.uniform(0.8, 2.0) * np.sin(X / rng.uniform(4, 7) + rng.uniform(0, 6)) * (body > 0)
    hx, hy = cx + rng.uniform(-5, 5), cy - rng.uniform(14, 20)
    ha, hb = rng.uniform(15, 20), rng.uniform(18, 24)
    head = _ellipsoid(X, Y, hx, hy, ha, hb, rng.uniform(45, 60))
    face = np.zeros_like(X)
    for _ in range(int(rng.integers(4, 8))):  # nose, brows, cheeks, hair curls
        px, py = hx + rng.uniform(-0.6, 0.6) * ha, hy + rng.uniform(-0.6, 0.6) * hb
        s = rng.uniform(2.0, 5.0)
        face += rng.uniform(-3, 6) * np.exp(-((X - px) ** 2 + (Y - py) ** 2) / (2 * s * s))
    head = np.where(head > 0, head + face, 0.0)
    return np.maximum(np.maximum(body, head), 0.0)


def sculpture_scene(rig: Rig, rng: np.random.Generator) -> Scene:
    """A background plane with one plaster-bust-like object: body, head, nose, brows, folds."""
    X, Y = _grid_mm(rig)
    height = _bust_height(X, Y, rng)
    depth = _background_depth(rig, rng.uniform(-3, 3), rng.uniform(-3, 3)) - height
    albedo = np.where(height > 0, _albedo(rng, X.shape, 0.85, 1.0), _albedo(rng, X.shape, 0.55, 0.8))
    return Scene("sculpture", depth, albedo)


def objects_scene(rig: Rig, rng: np.random.Generator) -> Scene:
    """Two to four separated objects (boxes, cylinders, domes, cones on pedestals) whose edges are
    steps of 15-45 mm: far taller than one fringe period of the highest frequency."""
    X, Y = _grid_mm(rig)
    height = np.zeros_like(X)
    w, h = X.max() - X.min(), Y.max() - Y.min()
    cells = [(i, j) for i in range(3) for j in range(2)]
    chosen = rng.choice(len(cells), size=int(rng.integers(2, 5)), replace=False)
    for k in chosen:
        i, j = cells[k]
        size = min(w / 3, h / 2) / 2 - 6  # half-width that leaves a gap between cells
        ox = X.min() + (i + 0.5) * w / 3 + rng.uniform(-3, 3)
        oy = Y.min() + (j + 0.5) * h / 2 + rng.uniform(-3, 3)
        radius = rng.uniform(0.6, 1.0) * size
        top = rng.uniform(15, 45)
        kind = rng.choice(["box", "cylinder", "dome", "cone"])
        dx, dy = X - ox, Y - oy
        if kind == "box":
            angle = rng.uniform(0, np.pi)
            ru = np.abs(dx * np.cos(angle) + dy * np.sin(angle))
            rv = np.abs(-dx * np.sin(angle) + dy * np.cos(angle))
            side = radius / np.sqrt(2)
            shape = np.where((ru < side) & (rv < side * rng.uniform(0.6, 1.0)), top + 0.05 * dx, 0.0)
        elif kind == "cylinder":
            shape = np.where(dx ** 2 + dy ** 2 < radius ** 2, top, 0.0)
        elif kind == "dome":
            shape = np.where(dx ** 2 + dy ** 2 < radius ** 2,
                             top * 0.5 + np.sqrt(np.clip(radius ** 2 - dx ** 2 - dy ** 2, 0, None)) * top * 0.5 / radius, 0.0)
        else:
            r = np.sqrt(dx ** 2 + dy ** 2)
            shape = np.where(r < radius, 12.0 + (top - 12.0) * (1 - r / radius), 0.0)
        height = np.maximum(height, shape)
    depth = _background_depth(rig, rng.uniform(-3, 3), rng.uniform(-3, 3)) - height
    albedo = np.where(height > 0, _albedo(rng, X.shape, 0.7, 1.0), _albedo(rng, X.shape, 0.55, 0.8))
    return Scene("objects", depth, albedo)


def scene_from_file(rig: Rig, path, kind: str = "height") -> Scene:
    """A user's map, one value per camera pixel, in millimetres: 'height' above the background plane
    at the standoff (towards the camera) or 'depth' along the camera axis. Formats: .npy, 16-bit PNG,
    TIFF; it is resized to the camera when its size differs."""
    path = Path(path)
    if kind not in ("height", "depth"):
        raise SimulationError(f"map kind must be 'height' or 'depth', got {kind!r}")
    if not path.is_file():
        raise SimulationError(f"scene file {path} does not exist")
    if path.suffix.lower() == ".npy":
        try:
            values = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as e:
            raise SimulationError(f"cannot read {path} as a .npy array: {e}") from None
    elif path.suffix.lower() in (".png", ".tif", ".tiff"):
        values = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if values is None:
            raise SimulationError(f"cannot decode image {path}")
    else:
        raise SimulationError(f"scene file {path} must be .npy, .png, .tif or .tiff")
    values = np.asarray(values)
    if values.ndim != 2 or values.dtype.kind not in "uif":
        raise SimulationError(f"scene file {path} must hold one 2-D numeric map, got {values.dtype} {values.shape}")
    values = values.astype(np.float64)
    if not np.all(np.isfinite(values)):
        raise SimulationError(f"scene file {path} has NaN or infinite values")
    if values.shape != (rig.height, rig.width):
        values = cv2.resize(values, (rig.width, rig.height), interpolation=cv2.INTER_LINEAR)
    depth = _background_depth(rig) - values if kind == "height" else values
    if depth.min() <= 0.1 * rig.standoff_mm:
        raise SimulationError(f"scene file {path} puts the surface at {depth.min():.1f} mm, too close to the camera")
    return Scene(path.stem, depth, np.full(depth.shape, 0.9))


# ---------------------------------------------------------------- scene families for training and evaluation

BACKGROUND_DEPTH_MM = (1100.0, 1300.0)  # background depth at the image centre
MAX_TILT_DEG = 35.0  # background tilt from fronto-parallel, towards any direction
SURFACE_DEPTH_MM = (1000.0, 1350.0)  # every surface stays inside this depth range
MAX_HEIGHT_MM = 100.0  # objects stand up to this far off their background
VOID_DEPTH_MM = 5000.0  # depth of 'no surface' (floating): far beyond the working range, albedo 0
ALBEDO_BASE = (0.15, 1.0)
ALBEDO_MIN = 0.02
TEXTURES = ("smooth", "checkers", "print", "stripes", "none")
TEXTURE_CONTRAST = (0.3, 0.9)
CHECKER_MM = (3.0, 20.0)
STRIPE_PERIOD_MM = (2.0, 15.0)
FREEFORM_HEIGHT_MM = (5.0, MAX_HEIGHT_MM)
BLOCK_HALF_SIZE_MM = (8.0, 35.0)
SPHERE_RADIUS_MM = (10.0, 50.0)
THIN_WIDTH_MM = (2.0, 6.0)
THIN_HEIGHT_MM = (3.0, 30.0)
# Per-scene photometry (random_rig)
AMBIENT = (0.0, 0.15)
GAIN = (0.4, 1.0)
NOISE_SIGMA = (0.5, 3.0)
BLUR_SIGMA_PX = (0.3, 1.2)


def _background(rig: Rig, rng: np.random.Generator, centre_mm=BACKGROUND_DEPTH_MM) -> np.ndarray:
    """A plane tilted by up to MAX_TILT_DEG towards a random direction, its depth at the image centre
    uniform in centre_mm (the top lowered where a steep tilt would take a corner beyond
    SURFACE_DEPTH_MM)."""
    tilt, direction = np.radians(rng.uniform(0.0, MAX_TILT_DEG)), rng.uniform(0.0, 2.0 * np.pi)
    slope_x, slope_y = np.tan(tilt) * np.cos(direction), np.tan(tilt) * np.sin(direction)
    unit = _background_depth(rig, np.degrees(np.arctan(slope_x)), np.degrees(np.arctan(slope_y))) / rig.standoff_mm
    low, high = centre_mm
    return rng.uniform(low, max(low, min(high, SURFACE_DEPTH_MM[1] / unit.max()))) * unit


def _on_background(background: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Depth of objects (height along the camera axis) standing on the background, all scaled down
    together where they would come nearer than SURFACE_DEPTH_MM."""
    top = height > 0
    scale = min(1.0, float(np.min((background[top] - SURFACE_DEPTH_MM[0]) / height[top]))) if top.any() else 1.0
    return background - scale * height


def _rotated(X, Y, cx: float, cy: float, angle: float):
    """Coordinates along and across the direction angle, from the point (cx, cy)."""
    c, s = np.cos(angle), np.sin(angle)
    return (X - cx) * c + (Y - cy) * s, -(X - cx) * s + (Y - cy) * c


def _centre(rng: np.random.Generator, X, Y) -> tuple[float, float]:
    """A random point well inside the view."""
    return rng.uniform(-0.8, 0.8) * X.max(), rng.uniform(-0.8, 0.8) * Y.max()


def _texture(rng: np.random.Generator, X, Y) -> np.ndarray:
    """A multiplicative albedo texture in [1 - contrast, 1], its kind drawn from TEXTURES."""
    kind = TEXTURES[int(rng.integers(len(TEXTURES)))]
    contrast = rng.uniform(*TEXTURE_CONTRAST)
    u, v = _rotated(X, Y, 0.0, 0.0, rng.uniform(0.0, np.pi))
    if kind == "smooth":
        return _albedo(rng, X.shape, 1.0 - contrast, 1.0)
    if kind == "checkers":
        size = rng.uniform(*CHECKER_MM)
        pattern = (np.floor(u / size) + np.floor(v / size)) % 2
    elif kind == "print":  # small blobs and strokes: thresholded fine noise
        field = _smooth_field(rng, X.shape, rng.uniform(1.5, 4.0))
        pattern = field > np.quantile(field, rng.uniform(0.5, 0.85))
    elif kind == "stripes":
        pattern = (u / rng.uniform(*STRIPE_PERIOD_MM)) % 1.0 < 0.5
    else:
        return np.ones_like(X)
    return 1.0 - contrast * pattern


def _surface_albedo(rng: np.random.Generator, X, Y) -> np.ndarray:
    return np.clip(rng.uniform(*ALBEDO_BASE) * _texture(rng, X, Y), ALBEDO_MIN, 1.0)


def _standing(rig: Rig, rng: np.random.Generator, name: str, height: np.ndarray, centre_mm) -> Scene:
    """Objects (a height map, 0 where there is none) on a sampled background, each with its own albedo."""
    X, Y = _grid_mm(rig)
    depth = _on_background(_background(rig, rng, centre_mm), height)
    on_object, on_background = _surface_albedo(rng, X, Y), _surface_albedo(rng, X, Y)
    return Scene(name, depth, np.where(height > 0, on_object, on_background))


def _freeform_height(X, Y, rng: np.random.Generator, islands: bool = False) -> np.ndarray:
    """1-6 Gaussian bumps or a smooth random field, peak FREEFORM_HEIGHT_MM; cut below a level (the
    foot), which leaves separate islands when islands is set."""
    if rng.random() < 0.5:
        field = np.zeros_like(X)
        for _ in range(int(rng.integers(1, 7))):
            cx, cy = _centre(rng, X, Y)
            sigma = rng.uniform(5.0, 40.0)
            field += rng.uniform(0.2, 1.0) * np.exp(-((X - cx) ** 2 + (Y - cy) ** 2) / (2 * sigma * sigma))
        level = rng.uniform(0.02, 0.1) if not islands else rng.uniform(0.1, 0.3)
    else:
        field = _smooth_field(rng, X.shape, rng.uniform(15.0, 80.0))
        level = rng.uniform(0.0 if not islands else 0.3, 0.6)
    field = np.clip(field / field.max() - level, 0.0, None) / (1.0 - level)
    return rng.uniform(*FREEFORM_HEIGHT_MM) * field


def _blocks_height(X, Y, rng: np.random.Generator) -> np.ndarray:
    """1-4 boxes or staircases (2-5 steps) up to MAX_HEIGHT_MM tall, sharp-edged, some rotated; about
    half of them set against the previous one."""
    height, previous = np.zeros_like(X), None
    for _ in range(int(rng.integers(1, 5))):
        a, b = rng.uniform(*BLOCK_HALF_SIZE_MM, size=2)
        if previous is not None and rng.random() < 0.5:  # touching: our -u face on its +u face
            px, py, angle, pa = previous
            cx, cy = px + (pa + a) * np.cos(angle), py + (pa + a) * np.sin(angle)
        else:
            cx, cy = _centre(rng, X, Y)
            angle = rng.uniform(0.0, np.pi) if rng.random() < 0.5 else 0.0
        u, v = _rotated(X, Y, cx, cy, angle)
        top = rng.uniform(10.0, MAX_HEIGHT_MM)
        if rng.random() < 0.5:
            shape = np.full_like(X, top)
        else:  # staircase rising along u
            steps = int(rng.integers(2, 6))
            shape = top * (np.floor(np.clip((u + a) / (2 * a), 0.0, 0.999) * steps) + 1) / steps
        height = np.maximum(height, np.where((np.abs(u) < a) & (np.abs(v) < b), shape, 0.0))
        previous = (cx, cy, angle, a)
    return height


def _spheres_height(X, Y, rng: np.random.Generator) -> np.ndarray:
    """1-4 spheres (partly sunk or resting), lying cylinders (axis in the image plane) and standing
    cylinders (flat discs on top), radius SPHERE_RADIUS_MM; about half touching the previous one."""
    height, previous = np.zeros_like(X), None
    for _ in range(int(rng.integers(1, 5))):
        r = rng.uniform(*SPHERE_RADIUS_MM)
        if previous is not None and rng.random() < 0.5:
            px, py, pr = previous
            direction = rng.uniform(0.0, 2.0 * np.pi)
            cx, cy = px + (pr + r) * np.cos(direction), py + (pr + r) * np.sin(direction)
        else:
            cx, cy = _centre(rng, X, Y)
        kind = int(rng.integers(3))
        if kind == 0:  # sphere with its centre lift mm above the background
            d2 = (X - cx) ** 2 + (Y - cy) ** 2
            shape = np.where(d2 < r * r, rng.uniform(0.0, r) + np.sqrt(np.clip(r * r - d2, 0.0, None)), 0.0)
        elif kind == 1:  # lying cylinder
            u, v = _rotated(X, Y, cx, cy, rng.uniform(0.0, np.pi))
            inside = (np.abs(u) < rng.uniform(r, 75.0)) & (np.abs(v) < r)
            shape = np.where(inside, r + np.sqrt(np.clip(r * r - v * v, 0.0, None)), 0.0)
        else:  # standing cylinder: a disc
            shape = np.where((X - cx) ** 2 + (Y - cy) ** 2 < r * r, rng.uniform(10.0, MAX_HEIGHT_MM), 0.0)
        height = np.maximum(height, shape)
        previous = (cx, cy, r)
    return height


def _thin_height(X, Y, rng: np.random.Generator) -> np.ndarray:
    """1-4 thin structures: a rod or plate seen edge-on, parallel ribs, or a lattice; parts
    THIN_WIDTH_MM wide and THIN_HEIGHT_MM tall."""
    height = np.zeros_like(X)
    for _ in range(int(rng.integers(1, 5))):
        width, tall = rng.uniform(*THIN_WIDTH_MM), rng.uniform(*THIN_HEIGHT_MM)
        u, v = _rotated(X, Y, *_centre(rng, X, Y), rng.uniform(0.0, np.pi))
        a, b, pitch = rng.uniform(15.0, 60.0), rng.uniform(10.0, 40.0), rng.uniform(width + 2.0, 20.0)
        kind = int(rng.integers(3))
        if kind == 0:  # one rod or plate
            part = (np.abs(v) < width / 2) & (np.abs(u) < a)
        else:  # ribs, crossed into a lattice for kind 2
            part = np.mod(v, pitch) < width
            if kind == 2:
                part |= np.mod(u, pitch) < width
            part &= (np.abs(u) < a) & (np.abs(v) < b)
        height = np.maximum(height, np.where(part, tall, 0.0))
    return height


def bust(rig: Rig, rng: np.random.Generator, centre_mm=BACKGROUND_DEPTH_MM) -> Scene:
    """The sculpture's bust, moved about the view, on a sampled background."""
    X, Y = _grid_mm(rig)
    dx, dy = rng.uniform(-30.0, 30.0), rng.uniform(-20.0, 20.0)
    return _standing(rig, rng, "bust", _bust_height(X - dx, Y - dy, rng), centre_mm)


def _standing_family(name: str, height_of):
    """A family of objects from height_of(X, Y, rng) on a sampled background."""
    def family(rig: Rig, rng: np.random.Generator, centre_mm=BACKGROUND_DEPTH_MM) -> Scene:
        X, Y = _grid_mm(rig)
        return _standing(rig, rng, name, height_of(X, Y, rng), centre_mm)
    family.__name__ = name
    return family


freeform = _standing_family("freeform", _freeform_height)
blocks = _standing_family("blocks", _blocks_height)
spheres = _standing_family("spheres", _spheres_height)
thin = _standing_family("thin", _thin_height)


def planes(rig: Rig, rng: np.random.Generator, centre_mm=BACKGROUND_DEPTH_MM) -> Scene:
    """A sampled background filling the view, nothing on it."""
    X, Y = _grid_mm(rig)
    return Scene("planes", _background(rig, rng, centre_mm), _surface_albedo(rng, X, Y))


def floating(rig: Rig, rng: np.random.Generator, centre_mm=BACKGROUND_DEPTH_MM) -> Scene:
    """1-3 freeform islands, blocks or spheres in the working range with no background: elsewhere a
    black void (albedo 0) at VOID_DEPTH_MM."""
    X, Y = _grid_mm(rig)
    height = np.zeros_like(X)
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(3))
        shape = (_freeform_height(X, Y, rng, islands=True) if kind == 0 else
                 _blocks_height(X, Y, rng) if kind == 1 else _spheres_height(X, Y, rng))
        height = np.maximum(height, shape)
    solid = height > 0
    depth = np.where(solid, _on_background(_background(rig, rng, centre_mm), height), VOID_DEPTH_MM)
    return Scene("floating", depth, np.where(solid, _surface_albedo(rng, X, Y), 0.0))


SCENE_FAMILIES = {f.__name__: f for f in (bust, freeform, blocks, spheres, thin, planes, floating)}
FAMILY_NAMES = tuple(SCENE_FAMILIES)


def random_rig(rng: np.random.Generator, base: Rig) -> Rig:
    """The base rig with per-scene photometry: ambient, gain, noise and defocus drawn uniformly."""
    # projector_gamma stays the base's: the patterns are pre-compensated for the rig's gamma, and a
    # different gamma would need a matching pattern set.
    return replace(base, ambient=rng.uniform(*AMBIENT), gain=rng.uniform(*GAIN),
                   noise_sigma=rng.uniform(*NOISE_SIGMA), blur_sigma_px=rng.uniform(*BLUR_SIGMA_PX))


SCENE_KINDS = ("sculpture", "objects", "plane") + FAMILY_NAMES


def make_scene(rig: Rig, kind: str, seed: int = 0, depth_mm: float | None = None) -> Scene:
    """A procedural scene by name (SCENE_KINDS), or a height map file when kind is a path."""
    rng = np.random.default_rng(seed)
    if kind == "sculpture":
        return sculpture_scene(rig, rng)
    if kind == "objects":
        return objects_scene(rig, rng)
    if kind == "plane":
        return plane_scene(rig, rig.standoff_mm if depth_mm is None else depth_mm)
    if kind in SCENE_FAMILIES:  # depth_mm given: the background's depth at the image centre
        return SCENE_FAMILIES[kind](rig, rng, *([] if depth_mm is None else [(depth_mm, depth_mm)]))
    return scene_from_file(rig, kind)


# ---------------------------------------------------------------- rendering

def projector_shadow(rig: Rig, depth: np.ndarray, cam: CameraIntrinsics, step_px: float = 0.5,
                     tolerance_mm: float = 0.1, needed: np.ndarray | None = None) -> np.ndarray:
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
        uq = (cam.fx * q[..., 0] / q[..., 2] + cam.cx).astype(np.float32)
        vq = (cam.fy * q[..., 1] / q[..., 2] + cam.cy).astype(np.float32)
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
            raise SimulationError(f"scene is {depth.shape[1]}x{depth.shape[0]} but the camera is {rig.width}x{rig.height}")
        self.rig, self.scene = rig, scene
        # Render a margin beyond the image (the scene's border extended) so that the blur near the
        # border mixes in what a real lens would, not a mirror image of the fringes.
        m = int(np.ceil(4 * rig.blur_sigma_px))
        cam = rig.camera()
        canvas = CameraIntrinsics(cam.width + 2 * m, cam.height + 2 * m, cam.fx, cam.fy, cam.cx + m, cam.cy + m)
        depth = cv2.copyMakeBorder(depth, m, m, m, m, cv2.BORDER_REPLICATE)
        albedo = cv2.copyMakeBorder(np.asarray(scene.albedo, np.float64), m, m, m, m, cv2.BORDER_REPLICATE)
        x, y = canvas.rays()
        self.xp, self.yp, zp = rig.to_projector(np.stack([x * depth, y * depth, depth], axis=-1))
        inside = (zp > 0) & (self.xp >= -0.5) & (self.xp <= rig.projector_width - 0.5) & \
                 (self.yp >= -0.5) & (self.yp <= rig.projector_height - 0.5)
        surface = albedo > 0  # albedo 0 is a void (no surface in range): never valid, no shadow needed
        self.lit = inside & surface & ~projector_shadow(rig, depth, canvas, needed=surface)
        self.reflect = (rig.full_scale * rig.gain * albedo * self.lit).astype(np.float32)
        self.crop = (slice(m, m + rig.height), slice(m, m + rig.width))
        self._bilinear = None  # for full pattern images, made on first use

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
        return Capture(np.empty((0, self.rig.height, self.rig.width), np.uint8), np.asarray(self.scene.depth_mm, np.float64),
                       self.lit[self.crop], coord[self.crop])


def render(rig: Rig, scene: Scene, patterns: PatternSet, rng: np.random.Generator | None = None) -> Capture:
    """The images the camera captures of the scene under each pattern, with the exact ground truth."""
    check_patterns(rig, patterns)
    renderer = SceneRenderer(rig, scene)
    vertical = patterns.orientation == "vertical"
    capture = renderer.truth(vertical)
    capture.images = np.stack([renderer.image(image, patterns.max_value, rng) for image in pattern_images(patterns)])
    return capture
