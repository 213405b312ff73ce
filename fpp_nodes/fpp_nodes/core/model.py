"""A single-shot depth model: an ONNX file and its card, run with onnxruntime (no torch).

The card (<model>.yaml, written by training.export) says what the model expects; loading checks the
file against the card's sha256, and every frame against the card's camera size.
"""
from __future__ import annotations

import hashlib
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import yaml

from .reconstruct import QualityLimits, drop_flying_pixels, full_scale

STRIDE = 32
# Local fringe contrast is measured over one fringe period of the default rig's highest frequency
# (9 camera pixels): it masks the inside of every shadow; a longer window lets thin shadows through.
CONTRAST_WINDOW = 9
MIN_MODULATION = 0.05  # as the multi-shot path's QualityLimits: a fraction of full scale


class ModelError(ValueError):
    """A model or card that is missing, corrupt or does not fit the images."""


def default_model_path() -> str:
    """The model trained by the project's documented command, shipped in the package."""
    return str(resources.files("fpp_nodes") / "data" / "models" / "unet.onnx")


class DepthModel:
    def __init__(self, path, providers=("CPUExecutionProvider",), threads: int = 2):
        import onnxruntime as ort
        path = Path(path)
        card_path = path.with_suffix(".yaml")
        if not path.is_file():
            raise ModelError(f"model {path} does not exist")
        if not card_path.is_file():
            raise ModelError(f"model {path} has no card {card_path.name} beside it")
        try:
            self.card = yaml.safe_load(card_path.read_text())
            expected_sha = self.card["sha256"]
            self.downsample = int(self.card["input"]["downsample"])
            camera = self.card["input"]["camera"]
            self.size = (int(camera["width"]), int(camera["height"]))
        except (yaml.YAMLError, KeyError, TypeError, ValueError) as e:
            raise ModelError(f"model card {card_path} is malformed ({type(e).__name__}: {e})") from None
        actual = hashlib.sha256(path.read_bytes()).hexdigest()
        if actual != expected_sha:
            raise ModelError(f"model {path} does not match its card: sha256 {actual[:12]}... != {str(expected_sha)[:12]}...")
        available = ort.get_available_providers()
        missing = [p for p in providers if p not in available]
        if missing:
            raise ModelError(f"execution providers {missing} are not available here (have {available})")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        try:
            self.session = ort.InferenceSession(str(path), options, providers=list(providers))
        except Exception as e:  # onnxruntime raises its own types for corrupt files
            raise ModelError(f"cannot load model {path}: {str(e).splitlines()[0]}") from None
        self.providers = self.session.get_providers()

    def check(self, image: np.ndarray) -> None:
        if image.ndim != 2 or (image.shape[1], image.shape[0]) != self.size:
            raise ModelError(f"the model takes {self.size[0]}x{self.size[1]} images (its card), got "
                             f"{'x'.join(map(str, image.shape[::-1]))}")
        if image.dtype not in (np.uint8, np.uint16):
            raise ModelError(f"the model takes mono8 or mono16 images, got {image.dtype}")

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Depth in mm (float32, camera size) of one fringe image, NaN where it is not to be trusted
        (see trusted_single_shot)."""
        self.check(image)
        x = image.astype(np.float32) * np.float32(1.0 / np.iinfo(image.dtype).max)
        w, h = self.size[0] // self.downsample, self.size[1] // self.downsample
        if self.downsample > 1:
            x = cv2.resize(x, (w, h), interpolation=cv2.INTER_AREA)
        x = cv2.copyMakeBorder(x, 0, (-h) % STRIDE, 0, (-w) % STRIDE, cv2.BORDER_REPLICATE)
        depth = self.session.run(["depth_mm"], {"image": x[None, None]})[0][0, 0, :h, :w]
        depth = cv2.resize(depth, self.size, interpolation=cv2.INTER_LINEAR) if self.downsample > 1 else depth
        return trusted_single_shot(depth, image)


def trusted_single_shot(depth: np.ndarray, image: np.ndarray,
                        max_depth_step_mm: float = QualityLimits.max_depth_step_mm) -> np.ndarray:
    """Set a network's depth to NaN (in place) where the image shows no usable fringes, and where it
    smears a depth edge: a pixel whose depth differs from a neighbour's by more than max_depth_step_mm,
    the multi-shot path's flying-pixel rule. A network smooths a depth step across a few pixels; on
    the multi-object test set the rule took its half-order errors from 0.29% to 0.007% of pixels."""
    depth[~fringe_mask(image)] = np.nan
    depth[~drop_flying_pixels(depth, max_depth_step_mm)] = np.nan
    return depth


def fringe_mask(image: np.ndarray, min_modulation: float = MIN_MODULATION, window: int = CONTRAST_WINDOW) -> np.ndarray:
    """Pixels of a single fringe image whose depth a network can know: the local fringe modulation
    (sqrt(2) x the standard deviation over the window, the amplitude of a sinusoid) is at least
    min_modulation of full scale, and no pixel near it is saturated (clipped fringes). A network
    answers everywhere; this keeps it from answering in shadows, in the dark and in glare."""
    scale = full_scale(image.dtype)
    mean = cv2.boxFilter(image, cv2.CV_32F, (window, window))
    variance = cv2.sqrBoxFilter(image, cv2.CV_32F, (window, window))
    variance -= cv2.multiply(mean, mean)
    ok = variance >= 0.5 * (min_modulation * scale) ** 2
    saturated = (image >= scale).astype(np.uint8)
    if saturated.any():
        ok &= cv2.dilate(saturated, np.ones((window, window), np.uint8)) == 0
    return ok
