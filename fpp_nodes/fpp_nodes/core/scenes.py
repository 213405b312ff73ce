"""Synthetic scenes for the simulated rig (simulation.py renders them): depth the camera sees at
every pixel, and albedo.

Training and evaluation scenes come in families (SCENE_FAMILIES: bust, freeform, blocks, spheres,
thin, planes, floating, reliefs) that cover the working volume: a background plane at 1100-1300 mm
depth at the image centre, tilted by up to 35 degrees in any direction, or no background at all
(floating objects before a black void); objects up to 100 mm tall on it, or reliefs 0.5-8 mm high or
deep; every surface between 1000 and 1350 mm. Albedo 0.15-1.0, times a texture: smooth, checkers,
print, stripes or none, drawn independently for objects and background. The fixed scenes (sculpture,
objects, plane) and height or depth maps from files are here too (make_scene).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .patterns import PatternSet, composite_phases
from .simulation import Rig, Scene, SceneRenderer, SimulationError


def _grid_mm(rig: Rig):
    """Metric coordinates (X, Y) of every pixel's footprint on the plane at the standoff."""
    x, y = rig.camera().rays()
    return x * rig.standoff_mm, y * rig.standoff_mm


def _background_depth(rig: Rig, tilt_x_deg: float = 0.0, tilt_y_deg: float = 0.0, offset_mm: float = 0.0):
    """Depth of the plane Z = Z0 + X tan(a) + Y tan(b) along every camera ray."""
    x, y = rig.camera().rays()
    return (rig.standoff_mm + offset_mm) / (
        1.0 - x * np.tan(np.radians(tilt_x_deg)) - y * np.tan(np.radians(tilt_y_deg))
    )


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
            shape = np.where(dx**2 + dy**2 < radius**2, top, 0.0)
        elif kind == "dome":
            shape = np.where(
                dx**2 + dy**2 < radius**2,
                top * 0.5 + np.sqrt(np.clip(radius**2 - dx**2 - dy**2, 0, None)) * top * 0.5 / radius,
                0.0,
            )
        else:
            r = np.sqrt(dx**2 + dy**2)
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
RELIEF_HEIGHT_MM = (0.5, 8.0)
# Per-scene photometry (random_rig)


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


def _reliefs_height(X, Y, rng: np.random.Generator) -> np.ndarray:
    """2-8 sharp-edged features RELIEF_HEIGHT_MM high (log-uniform), a third of them engraved (negative):
    rotated plates, discs, strokes and low staircases, as embossed print, labels and machined parts
    have. Steps under half a fringe order (4.7 mm in the default rig) keep the surface's phase
    continuous, so the decoder sees no step there: only the network could keep their edges sharp, and
    the shipped one smooths them (scripts/low_reliefs.py)."""
    height = np.zeros_like(X)
    low, high = np.log(RELIEF_HEIGHT_MM)
    for _ in range(int(rng.integers(2, 9))):
        h = np.exp(rng.uniform(low, high)) * (-1.0 if rng.random() < 1 / 3 else 1.0)
        u, v = _rotated(X, Y, *_centre(rng, X, Y), rng.uniform(0.0, np.pi))
        kind = int(rng.integers(4))
        if kind == 0:  # plate
            a, b = rng.uniform(5.0, 40.0, size=2)
            shape = np.where((np.abs(u) < a) & (np.abs(v) < b), h, 0.0)
        elif kind == 1:  # disc
            shape = np.where(u * u + v * v < rng.uniform(4.0, 35.0) ** 2, h, 0.0)
        elif kind == 2:  # stroke, as a letter's
            shape = np.where((np.abs(u) < rng.uniform(5.0, 40.0)) & (np.abs(v) < rng.uniform(0.5, 2.5)), h, 0.0)
        else:  # staircase of 2-4 steps rising along u
            a, b, steps = rng.uniform(10.0, 40.0), rng.uniform(8.0, 30.0), int(rng.integers(2, 5))
            rise = h * (np.floor(np.clip((u + a) / (2 * a), 0.0, 0.999) * steps) + 1) / steps
            shape = np.where((np.abs(u) < a) & (np.abs(v) < b), rise, 0.0)
        height = np.where(shape != 0, shape, height)  # the later feature on top
    return height


def reliefs(rig: Rig, rng: np.random.Generator, centre_mm=BACKGROUND_DEPTH_MM) -> Scene:
    """Low reliefs (_reliefs_height) on a sampled background, of the background's material half the time;
    engraved parts kept inside SURFACE_DEPTH_MM."""
    X, Y = _grid_mm(rig)
    height = _reliefs_height(X, Y, rng)
    depth = np.minimum(_on_background(_background(rig, rng, centre_mm), height), SURFACE_DEPTH_MM[1])
    background = _surface_albedo(rng, X, Y)
    features = background if rng.random() < 0.5 else _surface_albedo(rng, X, Y)
    return Scene("reliefs", depth, np.where(height != 0, features, background))


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
        shape = (
            _freeform_height(X, Y, rng, islands=True)
            if kind == 0
            else _blocks_height(X, Y, rng)
            if kind == 1
            else _spheres_height(X, Y, rng)
        )
        height = np.maximum(height, shape)
    solid = height > 0
    depth = np.where(solid, _on_background(_background(rig, rng, centre_mm), height), VOID_DEPTH_MM)
    return Scene("floating", depth, np.where(solid, _surface_albedo(rng, X, Y), 0.0))


SCENE_FAMILIES = {f.__name__: f for f in (bust, freeform, blocks, spheres, thin, planes, floating, reliefs)}
FAMILY_NAMES = tuple(SCENE_FAMILIES)


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


# Textures the scene generator never draws (export's hard validation scenes, scripts/single_shot_conditions.py):
# texture(rng, patterns, xp, yp) -> the albedo's factor at every pixel, xp and yp the projector column and row
# its surface point lies on.


def grating_texture(contrast: float, which: int):
    """Stripes where the composite's grating which (0 the carrier, 1.. its codes) falls on the surface: the
    albedo the projected grating would print there, which one image cannot tell from the grating itself."""

    def texture(rng, patterns, xp, yp):
        phase = composite_phases(patterns, xp, yp)[which] + rng.uniform(0, 2 * np.pi)
        return 1 - contrast * 0.5 * (1 + np.cos(phase))

    return texture


def black_print(rng, patterns, xp, yp):  # blobs and strokes of ink 2 px and up, on white
    field = cv2.GaussianBlur(rng.standard_normal(xp.shape), (0, 0), 2.0)
    return 1 - 0.97 * (field > 0.5 * field.std())


def pink_noise(rng, patterns, xp, yp):  # every scale at once, as natural surfaces are
    ky, kx = np.meshgrid(np.fft.fftfreq(xp.shape[0]), np.fft.fftfreq(xp.shape[1]), indexing="ij")
    field = np.fft.ifft2(np.fft.fft2(rng.standard_normal(xp.shape)) / np.maximum(np.hypot(kx, ky), 1e-3)).real
    return 1 - 0.9 * (field - field.min()) / (field.max() - field.min())


def fine_stripes(period_px: float):
    """Stripes period_px camera pixels apart (4 px: 1 mm at the stand-off), contrast 0.8, any direction."""

    def texture(rng, patterns, xp, yp):
        y, x = np.indices(xp.shape)
        angle = rng.uniform(0, np.pi)
        return 1 - 0.8 * (((x * np.cos(angle) + y * np.sin(angle)) / period_px + rng.uniform()) % 1.0 < 0.5)

    return texture


def textured(rig: Rig, patterns: PatternSet, scene: Scene, texture, seed: int) -> Scene:
    """The scene with every surface of albedo 0.8 times texture(rng, patterns, xp, yp)."""
    xp, yp = SceneRenderer(rig, scene).projector_xy
    albedo = 0.8 * texture(np.random.default_rng([seed, 2]), patterns, xp, yp)
    return Scene(scene.name, scene.depth_mm, np.where(scene.albedo > 0, albedo, 0.0))


# Stripes near the carrier: periods of these times its own in the projector, within this angle of its fringes
CARRIER_STRIPE_PERIODS, CARRIER_STRIPE_DEG = (0.6, 1.45), 25.0


def striped_like_the_carrier(rig: Rig, patterns: PatternSet, scene: Scene, seed: int) -> Scene:
    """The scene with its albedo times square stripes near the composite's carrier (CARRIER_STRIPE_PERIODS
    times its period, within CARRIER_STRIPE_DEG of its fringes, wherever a surface lies: drawn in the
    projector), contrast TEXTURE_CONTRAST. One image reads them as a shift of the carrier's phase except
    through what they do to the code gratings (their sidebands), so a network learns that only from
    scenes that hold them (docs/single-shot.md)."""
    xp, yp = SceneRenderer(rig, scene).projector_xy
    rng = np.random.default_rng([seed, 5])
    angle = np.radians(rng.uniform(-CARRIER_STRIPE_DEG, CARRIER_STRIPE_DEG))
    period = patterns.width / patterns.frequencies[-1] * rng.uniform(*CARRIER_STRIPE_PERIODS)
    stripes = ((xp * np.cos(angle) + yp * np.sin(angle)) / period + rng.random()) % 1.0 < 0.5
    return Scene(scene.name, scene.depth_mm, scene.albedo * (1.0 - rng.uniform(*TEXTURE_CONTRAST) * stripes))


# Bars near the carrier: each bar and gap this many of its periods wide in the projector, at random
BAR_WIDTH_PERIODS = (0.15, 1.0)


def barred_near_the_carrier(rig: Rig, patterns: PatternSet, scene: Scene, seed: int) -> tuple[Scene, np.ndarray]:
    """The scene with bars of random widths (bars and gaps BAR_WIDTH_PERIODS times the carrier's period,
    within CARRIER_STRIPE_DEG of its fringes: drawn in the projector), contrast TEXTURE_CONTRAST, on
    patches over about half the view; and those patches, dilated by a pixel (bool, the camera's pixels).
    One image cannot tell such an albedo from the carrier's phase, so training teaches the network to
    show no fringes on the patches (training.dataset's composite_bars) instead of guessing."""
    xp, yp = SceneRenderer(rig, scene).projector_xy
    rng = np.random.default_rng([seed, 6])
    angle = np.radians(rng.uniform(-CARRIER_STRIPE_DEG, CARRIER_STRIPE_DEG))
    period = patterns.width / patterns.frequencies[-1]
    across = np.nan_to_num(xp * np.cos(angle) + yp * np.sin(angle))
    across = across - across.min() + rng.uniform(0, period)
    count = int(across.max() / (BAR_WIDTH_PERIODS[0] * period)) + 2
    edges = np.cumsum(rng.uniform(*BAR_WIDTH_PERIODS, size=count) * period)
    bars = np.searchsorted(edges, across) % 2 == 1
    patches = cv2.GaussianBlur(rng.standard_normal(xp.shape), (0, 0), 40.0) > 0
    albedo = scene.albedo * (1.0 - rng.uniform(*TEXTURE_CONTRAST) * (bars & patches))
    refused = cv2.dilate((patches & (scene.albedo > 0)).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    return Scene(scene.name, scene.depth_mm, albedo), refused


def board_scene(rig: Rig, board, rotation: np.ndarray, translation_mm: np.ndarray) -> Scene:
    """A printed calibration board (core.board.Board) at a pose: board point b is at rotation @ b +
    translation_mm in the camera's frame. Its print is averaged over 4 x 4 points in each pixel, as
    sharp as a real print before the camera's blur."""
    x, y = rig.camera().rays()
    normal = rotation[:, 2]
    offset = normal @ translation_mm
    gradients = [np.gradient(a, axis=k) for a in (x, y) for k in (1, 0)]  # dx/du, dx/dv, dy/du, dy/dv
    albedo = np.zeros(x.shape)
    offsets = (np.arange(4) + 0.5) / 4 - 0.5  # 8 x 8 points moved the corners by under 0.01 px
    for du in offsets:
        for dv in offsets:
            xs = x + du * gradients[0] + dv * gradients[1]
            ys = y + du * gradients[2] + dv * gradients[3]
            depth = offset / (normal[0] * xs + normal[1] * ys + normal[2])
            b = (np.stack([xs * depth, ys * depth, depth], axis=-1) - translation_mm) @ rotation
            albedo += board.albedo(b[..., 0], b[..., 1]) / offsets.size**2
    depth = offset / (normal[0] * x + normal[1] * y + normal[2])
    if not (depth > 0).all():
        raise SimulationError("the board's plane passes behind the camera")
    return Scene("board", depth, albedo)


def board_poses(rig: Rig, board, count: int, rng: np.random.Generator, max_tilt_deg: float = 45.0) -> list:
    """count (rotation, translation_mm) poses of the board, as a user holds one: the whole board in
    view, its centre at 1100-1300 mm, tilted 10 deg to max_tilt_deg about a random axis in the image
    plane and turned up to 15 deg in its own plane."""
    cam, poses = rig.camera(), []
    corners = np.array([[-2, -2, 0], [board.cols, -2, 0], [-2, board.rows, 0], [board.cols, board.rows, 0]])
    corners = corners * board.square_mm - board.centre()
    for _ in range(1000 * count):
        if len(poses) == count:
            return poses
        angle = rng.uniform(0, 2 * np.pi)
        axis = np.array([np.cos(angle), np.sin(angle), 0.0])
        tilt = cv2.Rodrigues(axis * np.radians(rng.uniform(10.0, max_tilt_deg)))[0]
        turn = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(rng.uniform(-15.0, 15.0))]))[0]
        rotation = tilt @ turn
        z = rng.uniform(1100.0, 1300.0)
        centre = np.array([*(rng.uniform(-0.25, 0.25, 2) * np.array([cam.width, cam.height]) / cam.fx * z), z])
        u, v = cam.project(corners @ rotation.T + centre)
        if (u > 5).all() and (u < cam.width - 6).all() and (v > 5).all() and (v < cam.height - 6).all():
            poses.append((rotation, centre - rotation @ board.centre()))
    raise SimulationError(f"a {board.cols}x{board.rows}:{board.square_mm:g} board does not fit the camera's view")
