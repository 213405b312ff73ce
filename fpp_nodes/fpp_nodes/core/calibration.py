"""Phase to depth: the rational model of Vo et al. (2012), the paper's equation (3),

    z = C p^T / D p^T,   p = {1, phi, u, u phi, v, v phi, u^2, u^2 phi, v^2, v^2 phi, uv, uv phi}

with C = {1, c1 .. c11} and D = {d0 .. d11}; its least-squares fit from captures of planes at known
depths; back-projection to XYZ; and the versioned calibration file that holds them.

Here z is the depth along the camera's optical axis, in millimetres, (u, v) the camera pixel
(column, row) and phi the unwrapped phase of the highest frequency.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass, replace
from functools import lru_cache
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import yaml

from .patterns import COMPOSITE_CODES, PatternError, PatternSet

TERMS = ("1", "phi", "u", "u*phi", "v", "v*phi", "u^2", "u^2*phi", "v^2", "v^2*phi", "u*v", "u*v*phi")
FORMAT_NAME = "fpp_calibration"
FORMAT_VERSION = 1


def default_calibration_path() -> str:
    """The simulated rig's calibration, shipped in the package (made by `fpp demo --seed 0`)."""
    return str(resources.files("fpp_nodes") / "data" / "sim_calibration.yaml")


class CalibrationError(ValueError):
    """A calibration that cannot be fitted, read or used."""


def pixel_grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates of an image of shape (height, width): u (1 x W) and v (H x 1), float64,
    broadcasting to the image."""
    return np.arange(shape[1], dtype=np.float64)[None, :], np.arange(shape[0], dtype=np.float64)[:, None]


def _uv_terms(u, v):
    """The phase-free factors of p, in pairs: p = [t, t phi for t in (1, u, v, u^2, v^2, uv)]."""
    u = np.asarray(u, np.float64)
    v = np.asarray(v, np.float64)
    return [np.ones(np.broadcast(u, v).shape), u + 0 * v, v + 0 * u, u * u + 0 * v, v * v + 0 * u, u * v]


@dataclass
class PixelModel:
    """The rational model at given pixels: z = (ca + cb phi) / (da + db phi), the phase-free terms
    computed once (RationalModel.at), for the many phases or depths asked of the same pixels."""

    ca: np.ndarray
    cb: np.ndarray
    da: np.ndarray
    db: np.ndarray

    def depth(self, phase):
        return (self.ca + self.cb * phase) / (self.da + self.db * phase)

    def phase_at_depth(self, depth):
        """The inverse: the unwrapped phase a pixel sees at a given depth."""
        return (self.ca - depth * self.da) / (depth * self.db - self.cb)

    def depth_per_radian(self, phase):
        """dz/dphi: how far a phase error moves the depth."""
        return (self.cb * self.da - self.ca * self.db) / (self.da + self.db * phase) ** 2


@dataclass
class RationalModel:
    c: np.ndarray  # 12 numerator coefficients, c[0] == 1
    d: np.ndarray  # 12 denominator coefficients

    def __post_init__(self):
        self.c = np.asarray(self.c, np.float64).reshape(-1)
        self.d = np.asarray(self.d, np.float64).reshape(-1)
        if self.c.size != 12 or self.d.size != 12:
            raise CalibrationError(f"the rational model needs 12 + 12 coefficients, got {self.c.size} + {self.d.size}")
        if not (np.all(np.isfinite(self.c)) and np.all(np.isfinite(self.d))):
            raise CalibrationError("rational model coefficients must be finite")
        if self.c[0] != 1.0:
            raise CalibrationError(f"c0 must be 1 (the model's scale is fixed by it), got {self.c[0]}")

    def linear_in_phase(self, u, v):
        """(Ca, Cb, Da, Db) with C p = Ca + Cb phi and D p = Da + Db phi at pixel(s) (u, v)."""
        t = _uv_terms(u, v)
        ca = sum(self.c[2 * k] * t[k] for k in range(6))
        cb = sum(self.c[2 * k + 1] * t[k] for k in range(6))
        da = sum(self.d[2 * k] * t[k] for k in range(6))
        db = sum(self.d[2 * k + 1] * t[k] for k in range(6))
        return ca, cb, da, db

    def at(self, u, v) -> PixelModel:
        return PixelModel(*self.linear_in_phase(u, v))

    def depth(self, phase, u, v):
        return self.at(u, v).depth(phase)

    def phase_at_depth(self, depth, u, v):
        """The inverse: the unwrapped phase a pixel sees at a given depth."""
        return self.at(u, v).phase_at_depth(depth)

    def depth_per_radian(self, phase, u, v):
        """dz/dphi: how far a phase error moves the depth."""
        return self.at(u, v).depth_per_radian(phase)


def design_matrix(u, v, phase, depth):
    """Rows of the linear fit C p - z D p = 0 with c0 = 1 moved to the right-hand side."""
    t = _uv_terms(u, v)
    p = np.empty((np.size(u), 12))
    for k in range(6):
        p[:, 2 * k] = t[k].ravel()
        p[:, 2 * k + 1] = (t[k] * phase).ravel()
    a = np.hstack([p[:, 1:], -np.asarray(depth).reshape(-1, 1) * p])
    return a, -p[:, 0]


def fit_rational_model(u, v, phase, depth, iterations: int = 3, gauge_weight: float = 1e-6) -> RationalModel:
    """Least-squares fit of C and D from samples (u, v, phi, z).

    The algebraic residual C p - z D p is divided by D p (reweighting from the previous iterate),
    which makes it the depth error in millimetres. Where the rig has no lens distortion the
    12-term model is redundant: multiplying C and D by the same (1 + a u + b v) changes nothing, so
    a tiny penalty on the second-order terms picks the member of that family without them.
    Columns are scaled to unit norm so that pixel and phase units do not ruin the conditioning.
    """
    u, v, phase, depth = (np.asarray(x, np.float64).ravel() for x in (u, v, phase, depth))
    ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(phase) & np.isfinite(depth)
    u, v, phase, depth = u[ok], v[ok], phase[ok], depth[ok]
    if u.size < 23:
        raise CalibrationError(f"need at least 23 valid samples to fit the rational model, got {u.size}")
    if np.unique(depth).size < 2:
        raise CalibrationError("need captures at two or more different depths")
    a, b = design_matrix(u, v, phase, depth)
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    a = a / scale
    second_order = np.zeros(23, bool)
    second_order[5:11] = True  # c6..c11 (indices shifted by the fixed c0)
    second_order[17:23] = True  # d6..d11
    penalty = np.sqrt(gauge_weight) * np.linalg.norm(b) * np.diag(second_order.astype(float))[second_order]
    weights = np.ones_like(b)
    for _ in range(iterations):
        lhs = np.vstack([a * weights[:, None], penalty])
        rhs = np.concatenate([b * weights, np.zeros(len(penalty))])
        x = np.linalg.lstsq(lhs, rhs, rcond=None)[0] / scale
        model = RationalModel(np.concatenate([[1.0], x[:11]]), x[11:])
        ca, cb, da, db = model.linear_in_phase(u, v)
        denom = np.abs(da + db * phase)
        weights = 1.0 / np.maximum(denom, 1e-12 * denom.max())
        weights /= weights.mean()
    return model


DISTORTION_TERMS = ("k1", "k2", "p1", "p2", "k3")  # OpenCV's plumb bob (ROS's CameraInfo "plumb_bob")


@dataclass
class CameraIntrinsics:
    """A pinhole camera with lens distortion (OpenCV's model: radial k1, k2, k3, tangential p1, p2).

    The phase-to-depth model is written in ideal pixel coordinates (ideal_pixels: where each pixel's
    ray would land in the same camera without distortion), so that it stays rational; depth is along
    the optical axis, and XYZ = depth * (x/z, y/z, 1) of each pixel's true ray (rays).

    bits: how many bits of each pixel value the camera uses, where fewer than its images' type holds (a
    12-bit camera's driver sending mono16 with values up to 4095); None: all of them. full_range
    brings such frames to their type's full scale, where saturation and the fringe thresholds are."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)
    bits: int | None = None

    def __post_init__(self):
        if self.width < 1 or self.height < 1:
            raise CalibrationError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise CalibrationError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        self.distortion = tuple(float(k) for k in self.distortion)
        if len(self.distortion) != len(DISTORTION_TERMS) or not np.all(np.isfinite(self.distortion)):
            raise CalibrationError(f"distortion must be 5 finite numbers {DISTORTION_TERMS}, got {self.distortion}")
        if self.bits is not None and not (type(self.bits) is int and 1 <= self.bits <= 16):
            raise CalibrationError(f"camera bits must be a whole number 1-16, got {self.bits!r}")

    @property
    def frame_dtype(self) -> type:
        """The type of its frames where bits tell it (mono16 above 8), else mono8's: what a node warms up on."""
        return np.uint16 if (self.bits or 8) > 8 else np.uint8

    def full_range(self, image: np.ndarray) -> np.ndarray:
        """A camera frame (or a stack) at its type's full scale: values of a camera with fewer bits
        than the type holds are widened by repeating their bits (4095 of 12 bits -> 65535, 0 -> 0,
        linear within a count), so that saturation and thresholds in fractions of full scale hold.
        A frame with a value the camera's bits cannot hold is an error (it was widened already, or
        the calibration names another camera)."""
        width = 8 * image.dtype.itemsize
        if self.bits is None or image.dtype.kind != "u" or self.bits == width:
            return image
        if self.bits > width:
            raise CalibrationError(f"a {self.bits}-bit camera's frames do not fit {image.dtype} (mono{width})")
        top = (1 << self.bits) - 1
        if (largest := int(image.max(initial=0))) > top:
            raise CalibrationError(
                f"frame has a value of {largest}, more than the {top} of the calibration's {self.bits}-bit camera"
            )
        wide, shift = np.zeros_like(image), width - self.bits
        while shift > -self.bits:  # the bits repeated below themselves until the type is full
            wide |= image << shift if shift >= 0 else image >> -shift
            shift -= self.bits
        return wide

    def narrow_hint(self, image: np.ndarray) -> str | None:
        """What to do about 16-bit frames that use only 12 bits or fewer while the calibration says
        nothing of the camera's bits: their saturation (4095 for 12 bits) would go unseen."""
        if self.bits is not None or image.dtype != np.uint16:
            return None
        largest = int(image.max(initial=0))
        for bits in (8, 10, 12, 14):
            if largest < 1 << bits:
                return (
                    f"mono16 frames reach only {largest} of 65535: a {bits}-bit camera? Give the calibration's "
                    f"camera 'bits: {bits}' (fpp calibrate takes it from the sensor description), or its "
                    "saturation goes unseen; or the scene is very dark"
                )
        return None

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width): an image's shape."""
        return self.height, self.width

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """x/z and y/z of every pixel's viewing ray (optical frame: x right, y down, z forward)."""
        if any(self.distortion):
            return _undistorted_rays(*astuple(self))
        u, v = pixel_grid(self.shape)
        return np.broadcast_to((u - self.cx) / self.fx, self.shape), np.broadcast_to(
            (v - self.cy) / self.fy, self.shape
        )

    def ideal_pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """Each pixel's coordinates in the same camera without distortion: the phase-to-depth model's
        (u, v). Without distortion the pixel grid itself (1 x W and H x 1, broadcasting)."""
        if not any(self.distortion):
            return pixel_grid(self.shape)
        x, y = self.rays()
        return self.fx * x + self.cx, self.fy * y + self.cy

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (u, v) of (..., 3) points in the optical frame, distortion applied."""
        x, y = points[..., 0] / points[..., 2], points[..., 1] / points[..., 2]
        k1, k2, p1, p2, k3 = self.distortion
        if any(self.distortion):
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            x, y = (
                x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y,
            )
        return self.fx * x + self.cx, self.fy * y + self.cy

    def to_dict(self) -> dict:
        d = {
            k: (int(getattr(self, k)) if k in ("width", "height") else float(getattr(self, k)))
            for k in ("width", "height", "fx", "fy", "cx", "cy")
        }
        if any(self.distortion):
            d["distortion"] = list(self.distortion)
        return {**d, "bits": self.bits} if self.bits is not None else d

    @classmethod
    def from_dict(cls, d: dict) -> CameraIntrinsics:
        """From to_dict's mapping; a camera without 'distortion' has none, one without 'bits' uses its
        images' whole type."""
        return cls(
            **{k: d[k] for k in ("width", "height", "fx", "fy", "cx", "cy")},
            distortion=d.get("distortion", (0,) * 5),
            bits=d.get("bits"),
        )


@lru_cache(maxsize=4)
def _undistorted_rays(*camera) -> tuple[np.ndarray, np.ndarray]:
    """A distorted camera's rays, by OpenCV's iterative undistortion run to convergence (1e-12)."""
    cam = CameraIntrinsics(*camera)
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=-1)[:, None, :]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    xy = cv2.undistortPoints(pixels, cam.matrix(), np.array(cam.distortion), None, None, None, criteria)
    xy = xy.reshape(cam.height, cam.width, 2)
    return xy[..., 0], xy[..., 1]


def back_project(depth: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """Organized XYZ (H, W, 3) float32 in the camera's optical frame, same units as depth; NaN stays NaN."""
    depth = np.asarray(depth, np.float32)
    x, y = _float32_rays(*astuple(camera))
    return cv2.merge([cv2.multiply(depth, x), cv2.multiply(depth, y), depth])


@lru_cache(maxsize=4)
def _float32_rays(*camera) -> tuple[np.ndarray, np.ndarray]:
    return tuple(np.ascontiguousarray(r, np.float32) for r in CameraIntrinsics(*camera).rays())


@dataclass
class Calibration:
    """Everything needed to turn a fringe sequence into depth: camera, model, pattern set; with the
    composite single-shot pattern also code_models, one per code grating (patterns.COMPOSITE_CODES),
    each telling that grating's row phase (its phase less the carrier's absolute phase / K) at any
    depth: that row phase plus the carrier's phase is the phase of a grating tilted across the
    baseline, so the same rational form holds it as well conditioned as the carrier (the row phase
    alone hardly moves with depth, and a fit of it alone amplifies noise). See code_row_phase_at_depth."""

    camera: CameraIntrinsics
    model: RationalModel
    patterns: PatternSet
    reference_depth_mm: float  # where the background sits; FTP uses it to choose the global fringe order
    code_models: tuple[RationalModel, ...] = ()
    # (near, far) mm: where surfaces may be, which places the composite code's orders (CompositeDecoder);
    # by default the depths the calibration saw. None: not given (calibrations before it; the
    # multi-shot path does not need it)
    working_range_mm: tuple[float, float] | None = None

    def __post_init__(self):
        self.code_models = tuple(self.code_models)
        if self.working_range_mm is not None:
            near, far = self.working_range_mm = tuple(float(z) for z in self.working_range_mm)
            if not (np.isfinite(far) and 0 < near < far):
                raise CalibrationError(f"working_range_mm must be [near, far] with 0 < near < far, got {[near, far]}")
        codes = len(COMPOSITE_CODES) if self.patterns.single_shot == "composite" else 0
        if len(self.code_models) != codes:
            raise CalibrationError(
                f"a calibration of a {self.patterns.single_shot!r} single-shot frame has {codes} code models, "
                f"this one has {len(self.code_models)}"
            )

    def with_papers_single_shot(self) -> Calibration:
        """The same rig showing the paper's single-shot frame instead of the composite: 16 frames."""
        return Calibration(
            self.camera,
            self.model,
            replace(self.patterns, single_shot="paper"),
            self.reference_depth_mm,
            working_range_mm=self.working_range_mm,
        )

    def centre_gradient(self, phase_at) -> np.ndarray:
        """(along a row, down a column) per pixel of phase_at(depth, u, v) at the image centre, in the
        middle of the working range (without one: at the reference depth): the fringes a network sees."""
        near, far = self.working_range_mm or (self.reference_depth_mm,) * 2
        cx, cy = self.camera.cx, self.camera.cy
        phase = phase_at((near + far) / 2, np.array([cx, cx + 1, cx]), np.array([cy, cy, cy + 1]))
        return phase[1:] - phase[0]

    def fringe_period_px(self) -> float:
        """The finest fringes' period in camera pixels (centre_gradient): what a network reading them sees."""
        return float(2 * np.pi / np.hypot(*self.centre_gradient(self.model.phase_at_depth)))

    def code_row_phase_at_depth(self, code: int, depth, u, v):
        """Code grating number code's row phase a pixel sees at a depth (composite calibrations only)."""
        return self.code_row_phases(u, v)(code, depth)

    def code_row_phases(self, u, v):
        """code_row_phase_at_depth at fixed pixels, the models' terms computed once: f(code, depth)."""
        carrier, codes = self.model.at(u, v), [m.at(u, v) for m in self.code_models]
        return lambda code, depth: codes[code].phase_at_depth(depth) - carrier.phase_at_depth(depth)

    def code_phases_at_depth(self, depth, carrier_phase, u, v) -> list:
        """Each code grating's phase a pixel sees at a depth, given its absolute carrier phase there: the
        code's row phase plus the carrier's phase divided by the orders one turn of the code spans
        (patterns.COMPOSITE_CODES). The one formula the data sets' targets, FTP and evaluate share."""
        row = self.code_row_phases(u, v)
        return [row(i, depth) + carrier_phase / orders for i, (orders, _) in enumerate(COMPOSITE_CODES)]

    def to_dict(self) -> dict:
        return {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "depth_unit": "mm",
            "camera": self.camera.to_dict(),
            "model": {"terms": list(TERMS), "c": self.model.c.tolist(), "d": self.model.d.tolist()},
            "patterns": self.patterns.to_dict(),
            "reference_depth_mm": float(self.reference_depth_mm),
            **({"working_range_mm": list(self.working_range_mm)} if self.working_range_mm else {}),
            **(
                {"code_models": [{"c": m.c.tolist(), "d": m.d.tolist()} for m in self.code_models]}
                if self.code_models
                else {}
            ),
        }

    @classmethod
    def from_dict(cls, d) -> Calibration:
        if not isinstance(d, dict):
            raise CalibrationError("calibration file is not a YAML mapping")
        if d.get("format") != FORMAT_NAME:
            raise CalibrationError(f"not a calibration file: 'format' is {d.get('format')!r}, expected {FORMAT_NAME!r}")
        if d.get("version") != FORMAT_VERSION:
            raise CalibrationError(
                f"calibration version {d.get('version')!r} is not supported (this build reads {FORMAT_VERSION})"
            )
        missing = [k for k in ("camera", "model", "patterns", "reference_depth_mm") if k not in d]
        if missing:
            raise CalibrationError(f"calibration is missing {', '.join(missing)}")
        if "code_model" in d:
            raise CalibrationError(
                "calibration made for an earlier composite pattern (one code grating): calibrate again "
                "(fpp calibrate) with this version's patterns"
            )
        try:
            camera = CameraIntrinsics.from_dict(d["camera"])
            model = RationalModel(d["model"]["c"], d["model"]["d"])
            patterns = PatternSet.from_dict(d["patterns"])
            reference = float(d["reference_depth_mm"])
            code_models = [RationalModel(m["c"], m["d"]) for m in d.get("code_models", [])]
            working_range = d.get("working_range_mm")
            if working_range is not None:
                if len(working_range) != 2:
                    raise ValueError(f"working_range_mm must be [near, far], got {working_range}")
                working_range = tuple(float(z) for z in working_range)
        except KeyError as e:
            raise CalibrationError(f"calibration is missing {e.args[0]!r}") from None
        except PatternError as e:
            raise CalibrationError(str(e)) from None
        except (TypeError, ValueError) as e:
            raise CalibrationError(f"calibration has a malformed value: {e}") from None
        return cls(camera, model, patterns, reference, code_models, working_range)

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    @classmethod
    def from_yaml(cls, text: str) -> Calibration:
        try:
            return cls.from_dict(yaml.safe_load(text))
        except yaml.YAMLError as e:
            raise CalibrationError(f"calibration is not valid YAML: {str(e).splitlines()[0]}") from None

    def save(self, path) -> None:
        Path(path).write_text(self.to_yaml())

    @classmethod
    def load(cls, path) -> Calibration:
        try:
            text = Path(path).read_text()
        except OSError as e:
            raise CalibrationError(f"cannot read calibration {path}: {e.strerror}") from None
        try:
            return cls.from_yaml(text)
        except CalibrationError as e:
            raise CalibrationError(f"{path}: {e}") from None
