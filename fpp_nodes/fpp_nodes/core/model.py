"""A single-shot depth model: an ONNX file and its card, run with onnxruntime (no torch).

The card (<model>.yaml, written by training.export) says what the model expects; loading checks the
file against the card's sha256, and every frame against the card's camera size.
"""

from __future__ import annotations

import hashlib
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import yaml

from . import fused
from .calibration import Calibration
from .patterns import CARRIER_AMPLITUDE, COMPOSITE_CODES, PatternError, PatternSet, composite_radiance
from .phase import PhaseError
from .reconstruct import (
    MAX_MISFIT_RAD,
    CompositeDecoder,
    QualityLimits,
    code_sidebands,
    depth_terms,
    drop_flying_pixels,
    full_scale,
)

STRIDE = 32
# Local fringe contrast is measured over one fringe period of the default rig's highest frequency
# (9 camera pixels): it masks the inside of every shadow; a longer window lets thin shadows through.
CONTRAST_WINDOW = 9
MIN_MODULATION = 0.05  # as the multi-shot path's QualityLimits: a fraction of full scale
# A composite network sees a rig's fringes at the period it was trained on: the image is resampled where
# the periods differ by more than this (surfaces tilted by 20 degrees in training already change it by 6%)
PERIOD_TOLERANCE = 0.05
RANGE_WARNING = "frames outside the working range"  # the warning's name, on /diagnostics and in fpp


class ModelError(ValueError):
    """A model or card that is missing, corrupt or does not fit the images."""


def default_model_path() -> str:
    """The shipped default: the composite pattern's network (make composite-model), which says NaN
    where it cannot tell the fringe order."""
    return str(resources.files("fpp_nodes") / "data" / "models" / "composite.onnx")


def paper_model_path() -> str:
    """The paper's UNet regressing depth (make paper-model), shipped for the reproduction (Table 1). It
    knows only its training family, a bust on a plane at the reference depth tilted at most 3 degrees,
    and is silently wrong elsewhere."""
    return str(resources.files("fpp_nodes") / "data" / "models" / "unet.onnx")


class DepthModel:
    """An exported single-shot model and its card. A composite model's network reads the pattern's
    phases off the image, which no rig's geometry enters; the rig's calibration (calibration, by
    default the card's: the training rig's) turns them into depth, so it runs on any rig that shows
    its pattern (use). The paper-pattern phase network's order is relative to its training rig's
    reference depth, so it decodes with its card's calibration only."""

    def __init__(self, path, providers=("CPUExecutionProvider",), threads: int = 2, calibration=None):
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
            self.trained_size = (int(camera["width"]), int(camera["height"]))
        except (yaml.YAMLError, KeyError, TypeError, ValueError) as e:
            raise ModelError(f"model card {card_path} is malformed ({type(e).__name__}: {e})") from None
        actual = hashlib.sha256(path.read_bytes()).hexdigest()
        if actual != expected_sha:
            raise ModelError(
                f"model {path} does not match its card: sha256 {actual[:12]}... != {str(expected_sha)[:12]}..."
            )
        try:
            self.reads = PatternSet.from_dict(self.card["patterns"]).single_shot  # which single-shot frame
        except (KeyError, TypeError, PatternError) as e:
            raise ModelError(f"model card {card_path} lacks a valid pattern set ({type(e).__name__}: {e})") from None
        available = ort.get_available_providers()
        missing = [p for p in providers if p not in available]
        if missing:
            raise ModelError(f"execution providers {missing} are not available here (have {available})")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        # no busy-waiting between runs: it took the core cnn_depth's decoding thread needs (threads 2: 62
        # against 43 ms of CPU a frame), and offline it bought nothing (docs/single-shot.md, the node's speed)
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(path), options, providers=list(providers))
        except Exception as e:  # onnxruntime raises its own types for corrupt files
            raise ModelError(f"cannot load model {path}: {str(e).splitlines()[0]}") from None
        self.providers = self.session.get_providers()
        self.output = self.session.get_outputs()[0].name
        # an output at 1/r of the input's resolution with r^2 times the channels, shuffled here (export)
        self.shuffle = int((self.card.get("output") or {}).get("pixel_shuffle", 1))
        self.decoder = self.card_calibration = self.calibration = None
        self.max_misfit_rad = MAX_MISFIT_RAD  # a composite frame whose codes miss by more is refused (scripts: inf)
        if self.output in ("fringe_order", "fringe_phases"):  # a phase-aware model: its card holds its calibration
            try:
                self.card_calibration = Calibration.from_dict(self.card["calibration"])
                self.min_confidence = float(self.card["decoding"]["min_confidence"])
                # the fringe mask's floor and the roughness rule, chosen with the threshold on validation
                # (cards before them: 5%, no roughness rule)
                self.min_modulation = float(self.card["decoding"].get("min_modulation", MIN_MODULATION))
                self.max_roughness_mm = float(self.card["decoding"].get("max_roughness_mm", np.inf))
                self.min_surface_px = int(self.card["decoding"].get("min_surface_px", 0))
                self.margin_px = int(self.card["decoding"].get("margin_px", 0))  # cards before it: none
                self.max_sideband = float(self.card["decoding"].get("max_sideband", np.inf))  # ... none
                self.max_outside = float(self.card["decoding"].get("max_outside", np.inf))  # ... none
            except (KeyError, TypeError, ValueError) as e:  # CalibrationError is a ValueError
                raise ModelError(
                    f"model card {card_path} lacks the calibration or decoding of a phase-aware "
                    f"model ({type(e).__name__}: {e})"
                ) from None
            if self.downsample != 1:
                raise ModelError(f"model card {card_path}: a phase-aware model runs at full resolution")
            if (
                self.output == "fringe_phases"
                and self.card["input"].get("layout") != TRAINING_LAYOUT
                and network_layout(self.card_calibration) != Layout()
            ):
                raise ModelError(
                    f"model {path} was trained on its rig's frames as they are (exported before 2026-12-05), and "
                    f"networks now read every rig's frames laid out as the simulated rig's ({TRAINING_LAYOUT}): "
                    "fine-tune it again from the shipped model (docs/real-rig.md)"
                )
            channels = self.session.get_outputs()[0].shape[1] // self.shuffle**2
            expected = 2 + 2 * len(COMPOSITE_CODES)
            if self.output == "fringe_phases" and channels != expected:
                raise ModelError(
                    f"model {path} gives {channels} channels: it was trained for another composite pattern "
                    f"(this one's carrier and {len(COMPOSITE_CODES)} code gratings give {expected})"
                )
        self.use(calibration)

    def use(self, calibration: Calibration | None) -> None:
        """Run on the rig of this calibration (None: the card's): it must show the model's single-shot
        frame, at the camera size the model was trained for unless it is a composite model, which reads
        any size, its images resampled so that their fringes have the period it was trained on. Nothing
        changes if the calibration cannot be used."""
        if calibration is not None and calibration is self.calibration:
            return  # the decoder's maps take a while to build
        size, scale, layout = self.trained_size, 1.0, Layout()
        if calibration is not None:
            if self.reads != calibration.patterns.single_shot:
                raise ModelError(
                    f"the model reads the {self.reads!r} single-shot frame but the calibration's pattern set "
                    f"has {calibration.patterns.single_shot!r} (set its patterns' single_shot, or use a model "
                    "trained for it)"
                )
            cam = calibration.camera
            if self.output == "fringe_phases":
                size, scale = (cam.width, cam.height), self.card_calibration.fringe_period_px()
                scale /= calibration.fringe_period_px()
                scale = 1.0 if abs(scale - 1) <= PERIOD_TOLERANCE else scale
            elif (cam.width, cam.height) != size:
                raise ModelError(
                    f"the model was trained for {size[0]}x{size[1]} images, "
                    f"the calibration's camera is {cam.width}x{cam.height}"
                )
        if self.output == "fringe_phases":
            layout = network_layout(calibration or self.card_calibration)
        if self.card_calibration is not None:  # a depth-regressing model has the rig's geometry in the network
            try:
                self.decoder = (
                    PhaseOrderDecoder(self.card_calibration)
                    if self.output == "fringe_order"
                    else CompositeDecoder(
                        calibration or self.card_calibration, self.min_surface_px, self.max_sideband, self.max_outside
                    )
                )
            except PhaseError as e:
                whose = "its card's" if calibration is None or self.output == "fringe_order" else "the rig's"
                raise ModelError(f"the model cannot decode with {whose} calibration: {e}") from None
        self.calibration, self.size, self.scale, self.layout = calibration, size, scale, layout
        # what the network reads: the image (laid out as training showed it) at 1/downsample, or resampled
        # to the trained fringe period
        self.input_size = tuple(round(n * scale) // self.downsample for n in layout.size(size))

    def warnings(self) -> dict[str, str]:
        """After a frame of a composite model: {what the frame was: what to say} where its scene, or part
        of it, seems to lie outside the working range (CompositeDecoder.range_warning), and where it
        refused surfaces for an albedo striped like the pattern's code gratings (CompositeDecoder.striped)."""
        said = {}
        if isinstance(self.decoder, CompositeDecoder) and (warning := self.decoder.range_warning()):
            said[RANGE_WARNING] = warning
        if getattr(self.decoder, "misfit", 0.0) > self.max_misfit_rad:
            said["frames from a rig that no longer fits its calibration"] = (
                f"the network's codes miss the orders they name by {self.decoder.misfit:.2f} rad, smoothly over the "
                f"frame (at most {self.max_misfit_rad} as calibrated): has the projector been turned or moved since "
                "calibrating? Every pixel given no depth: calibrate again"
            )
        if striped := getattr(self.decoder, "striped", 0.0):
            said["frames with surfaces striped like the pattern"] = (
                f"{striped:.1%} of the pixels with fringes lie on surfaces whose albedo swings the fringes' "
                "contrast at a code grating's frequency (stripes like a code's, or near it), which can move the "
                "fringe order one image reads: given no depth (the multi-shot path measures them)"
            )
        return said

    def check(self, image: np.ndarray) -> None:
        if image.ndim != 2 or (image.shape[1], image.shape[0]) != self.size:
            raise ModelError(
                f"the model takes {self.size[0]}x{self.size[1]} images (its calibration's camera), got "
                f"{'x'.join(map(str, image.shape[::-1]))}"
            )
        if image.dtype not in (np.uint8, np.uint16):
            raise ModelError(f"the model takes mono8 or mono16 images, got {image.dtype}")

    def frame(self, image: np.ndarray) -> np.ndarray:
        """A camera frame as the model reads it: checked, and at its type's full scale (the
        calibration camera's bits: CameraIntrinsics.full_range); what infer takes, and what the
        node hands network, sidebands and decode."""
        self.check(image)
        rig = self.calibration or self.card_calibration
        return image if rig is None else rig.camera.full_range(image)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Depth in mm (float32, camera size) of one fringe image, NaN where it is not to be trusted
        (see trusted_single_shot)."""
        return self.infer(image)[0]

    def outputs(self, image: np.ndarray) -> np.ndarray:
        """The network's outputs for one fringe image (decode's input): its channels at the network
        input's resolution; a phase-aware model's at the image's, where it read a resampled image."""
        return self.laid_out(self.network(image))

    def network(self, image: np.ndarray) -> np.ndarray:
        """outputs' first half, the network itself: its outputs as the file gives them (at 1/r of the
        padded input's resolution with r^2 times the channels, where the card says pixel_shuffle r).
        cnn_depth runs it on its network's thread, and laid_out on the decoding thread."""
        self.check(image)
        x = self.layout.shown(network_input(image))
        w, h = self.input_size
        if (w, h) != x.shape[::-1]:
            x = cv2.resize(x, (w, h), interpolation=cv2.INTER_AREA if w < x.shape[1] else cv2.INTER_LINEAR)
        x = cv2.copyMakeBorder(x, 0, (-h) % STRIDE, 0, (-w) % STRIDE, cv2.BORDER_REPLICATE)
        return self.session.run([self.output], {"image": x[None, None]})[0][0]

    def laid_out(self, raw: np.ndarray) -> np.ndarray:
        """outputs' second half: the network's outputs shuffled, cropped to its input and resampled to
        the image's size."""
        w, h = self.input_size
        out = (fused.pixel_shuffle(raw, self.shuffle) if self.shuffle > 1 else raw)[:, :h, :w]
        if self.scale != 1.0:
            size = self.layout.size(self.size)
            out = np.stack([cv2.resize(c, size, interpolation=cv2.INTER_LINEAR) for c in out])
        return self.layout.undone(out, self.size)

    def sidebands(self, image: np.ndarray, out: np.ndarray) -> np.ndarray | None:
        """The stripes rule's evidence, the image's code sidebands (code_sidebands), for a composite
        decoder with the rule; None otherwise."""
        striped_rule = np.isfinite(getattr(self.decoder, "max_sideband", np.inf))
        return code_sidebands(image, out) if striped_rule else None

    def infer(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(depth mm, confidence) of one fringe image. A phase-aware model's confidence is the
        probability that each pixel's fringe order is right (NaN depth below its threshold, and within
        its card's margin of a pixel refused where fringes show: refusal_margin; NaN itself where the
        image shows no usable fringes); a depth-regressing model has none."""
        image = self.frame(image)
        return self.decode(image, self.outputs(image))

    def warm_up(self) -> None:
        """Decode one frame of a made-up scene (warm_up_frame) so that onnxruntime's first run, and the
        first call of every compiled pass of the decoding (numba compiles each then, about 6 s on a fresh
        install, or loads its cached copy), come now: a black frame reaches only some of them, and the
        first camera frames came seconds late."""
        rig = self.calibration or self.card_calibration
        self.infer(np.zeros(self.size[::-1], np.uint8) if rig is None else warm_up_frame(rig))

    def decode(
        self, image: np.ndarray, out: np.ndarray, sidebands: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """infer's second half: the network's outputs for image -> (depth mm, confidence); sidebands:
        self.sidebands(image, out) where already taken (else taken here)."""
        if self.decoder is not None:
            fringes = decoded_fringes(image, out, self.min_modulation, self.decoder)
            if sidebands is None:
                sidebands = self.sidebands(image, out)
            # every pixel whose order its neighbours share
            depth, confidence = self.decoder(out, 0.0, fringes, sidebands)
            depth = trusted_single_shot(depth, image, fringes=fringes, max_roughness_mm=self.max_roughness_mm)
            depth[~confident(confidence, self.min_confidence)] = np.nan
            refusal_margin(depth, fringes, self.margin_px)
            if isinstance(self.decoder, CompositeDecoder) and self.decoder.misfit_of(out, depth) > self.max_misfit_rad:
                depth[...] = np.nan  # a rig its calibration no longer fits: every order may be wrong (warnings)
            return depth, confidence
        depth = cv2.resize(out[0], self.size, interpolation=cv2.INTER_LINEAR) if self.downsample > 1 else out[0]
        return trusted_single_shot(depth, image), None


# How every composite network is shown its frames (network_layout), as its card says (training.export)
TRAINING_LAYOUT = "the carrier's phase rising left to right, the first code's row phase top to bottom"


class Layout(NamedTuple):
    """How a rig's frames are turned to show the network their fringes as its training did: transposed
    (rows for columns), then mirrored along flipped (0: up-down, 1: left-right), then turned by turned_deg
    (anticlockwise as shown, cv2's sense) into the canvas that holds the whole frame; the network's
    outputs are turned back. The identity where the rig shows them as training did."""

    transposed: bool = False
    flipped: tuple[int, ...] = ()
    turned_deg: float = 0.0

    def _upright(self, size: tuple[int, int]) -> tuple[int, int]:
        return size[::-1] if self.transposed else size

    def turn(self, size: tuple[int, int]) -> tuple[np.ndarray, tuple[int, int]]:
        """The turn of a transposed and mirrored frame of that (width, height): its matrix (2 x 3,
        cv2.warpAffine's, frame to canvas) and the canvas's (width, height)."""
        w, h = size
        c, s = abs(np.cos(np.radians(self.turned_deg))), abs(np.sin(np.radians(self.turned_deg)))
        canvas = (int(np.ceil(w * c + h * s - 1e-6)), int(np.ceil(w * s + h * c - 1e-6)))
        matrix = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), self.turned_deg, 1.0)
        matrix[:, 2] += ((canvas[0] - w) / 2, (canvas[1] - h) / 2)  # centre on centre
        return matrix, canvas

    def size(self, size: tuple[int, int]) -> tuple[int, int]:
        """A frame's (width, height) as the network sees it."""
        return self.turn(self._upright(size))[1] if self.turned_deg else self._upright(size)

    def shown(self, image: np.ndarray) -> np.ndarray:
        """A frame (H, W) as the network is shown it."""
        x = np.ascontiguousarray(np.flip(image.T if self.transposed else image, self.flipped))
        if not self.turned_deg:
            return x
        matrix, canvas = self.turn(x.shape[::-1])
        return cv2.warpAffine(x, matrix, canvas, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def undone(self, out: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """The network's outputs (C, H, W) turned back to the layout of a frame of that (width, height)."""
        if self.turned_deg:
            upright = self._upright(size)
            matrix, _ = self.turn(upright)
            back = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
            out = np.stack([cv2.warpAffine(np.ascontiguousarray(c), matrix, upright, flags=back) for c in out])
        x = np.flip(out, [axis + 1 for axis in self.flipped])
        return np.ascontiguousarray(x.transpose(0, 2, 1) if self.transposed else x)


# Fringes tilted less than this in a frame are shown as they are: turning them bought nothing at 1-2 degrees of
# camera or projector roll (0.4 point less at 1), and from 5 on 1.8-12.6 points (runs/s86's throwaway scripts,
# two exploration scenes; docs/real-rig.md)
TILT_TOLERANCE_DEG = 2.0


def network_layout(calibration: Calibration) -> Layout:
    """How a composite rig's frames are turned (Layout) to show the network their fringes as every network
    is trained on them, the simulated rig's way: the carrier's phase rising left to right along the rows,
    the first code's rows rising down the columns (by the calibration's models at its image centre,
    Calibration.centre_gradient). A projector showing its image mirrored (rear or ceiling mode) mirrors
    them, a camera mounted turned a quarter (portrait) or a projector above the camera transposes them;
    a network reads the carrier of such frames wrongly (a mirrored carrier's phase backwards: every pixel
    was NaN). A camera or projector rolled about its axis tilts the fringes: by more than
    TILT_TOLERANCE_DEG, the frames are turned upright (the network read few codes at 10 degrees, none at
    20). A set recorded on such a rig is shown to the network the same way in training (training.train),
    so a fine-tune starts from weights that read its frames."""
    carrier = calibration.centre_gradient(calibration.model.phase_at_depth)  # (along a row, down a column)
    rows = calibration.centre_gradient(lambda depth, u, v: calibration.code_row_phase_at_depth(0, depth, u, v))
    transposed = bool(abs(carrier[1]) > abs(carrier[0]))
    if transposed:
        carrier, rows = carrier[::-1], rows[::-1]
    # image axis 0 runs up-down, axis 1 left-right
    flipped = (0,) * bool(rows[1] < 0) + (1,) * bool(carrier[0] < 0)
    tilt = float(np.degrees(np.arctan2(carrier[1] * (-1 if 0 in flipped else 1), abs(carrier[0]))))
    return Layout(transposed, flipped, tilt if abs(tilt) > TILT_TOLERANCE_DEG else 0.0)


def warm_up_frame(calibration: Calibration) -> np.ndarray:
    """The single-shot frame the calibration's camera would take, by its models, of a plane in the
    middle of the working range with a block before it and one beyond the range's far end: steps, an
    order outside the range and a shadowless plane, which every decoding path meets."""
    cam = calibration.camera
    near, far = calibration.working_range_mm or (calibration.reference_depth_mm,) * 2
    span = max(far - near, 0.1 * calibration.reference_depth_mm)
    depth = np.full(cam.shape, (near + far) / 2)
    h, w = cam.shape
    depth[h // 4 : h // 2, w // 4 : w // 2] = near + 0.2 * span
    depth[h // 4 : h // 2, w // 2 : 3 * w // 4] = far + 0.3 * span
    u, v = cam.ideal_pixels()
    carrier = calibration.model.phase_at_depth(depth, u, v)
    if calibration.patterns.single_shot == "composite":
        radiance = composite_radiance(carrier, calibration.code_phases_at_depth(depth, carrier, u, v))
    else:  # the paper's: the finest fringes' first image
        radiance = 0.5 + 0.5 * np.cos(carrier)
    top = (1 << cam.bits) - 1 if cam.bits else np.iinfo(cam.frame_dtype).max
    return np.round(top * (0.1 + 0.8 * radiance)).astype(cam.frame_dtype)


def confident(confidence: np.ndarray, min_confidence: float) -> np.ndarray:
    """The pixels whose order confidence reaches min_confidence, never one at 0: a rule refused it (an
    albedo striped like the codes, too small a surface, a surface outside the working range), which a
    threshold of 0 must not undo."""
    return (confidence >= min_confidence) & (confidence > 0)


def network_input(image: np.ndarray) -> np.ndarray:
    """The camera image as every network takes it: float32, 0 to 1 of the camera's full scale."""
    return image.astype(np.float32) * np.float32(1.0 / full_scale(image.dtype))


def order_confidence(log_sigma: np.ndarray) -> np.ndarray:
    """P(|error| < half an order) for a Gaussian of standard deviation exp(log_sigma) orders:
    erf(0.5 / (sqrt(2) sigma)), by Abramowitz and Stegun 7.1.26 (error < 1.5e-7)."""
    x = np.float32(0.5 / np.sqrt(2.0)) * np.exp(-log_sigma)
    t = 1.0 / (1.0 + np.float32(0.3275911) * x)
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))))
    return (1.0 - poly * np.exp(-x * x)).astype(np.float32)


class PhaseOrderDecoder:
    """A phase-aware network's output -> depth, for the calibration it was trained with.

    The wrapped phase is the angle of (denominator, numerator); the order is the whole number of
    periods that brings it nearest to the network's coarse absolute phase (the reference-depth phase
    plus r orders); the rational model turns the absolute phase into depth. Pixels whose order the
    network is less sure of than min_confidence are NaN."""

    def __init__(self, calibration: Calibration):
        cam = calibration.camera
        u, v = cam.ideal_pixels()
        self.reference = np.broadcast_to(
            calibration.model.phase_at_depth(calibration.reference_depth_mm, u, v), cam.shape
        ).astype(np.float32)
        self.terms = depth_terms(calibration)

    def __call__(
        self, out: np.ndarray, min_confidence: float, fringes: np.ndarray | None = None, sidebands=None
    ) -> tuple[np.ndarray, np.ndarray]:
        """As CompositeDecoder's (the paper's pattern has no code gratings: sidebands are ignored)."""
        num, den, orders, log_sigma = (np.ascontiguousarray(c, np.float32) for c in out)
        wrapped = cv2.phase(den, num)  # atan2(num, den) in [0, 2 pi)
        coarse = self.reference + np.float32(2 * np.pi) * orders
        phase = wrapped + np.float32(2 * np.pi) * np.rint((coarse - wrapped) * np.float32(1 / (2 * np.pi)))
        ca, cb, da, db = self.terms
        depth = (ca + cb * phase) / (da + db * phase)
        confidence = order_confidence(log_sigma)
        if fringes is not None:
            confidence[~fringes] = np.nan  # no fringes: nothing to be confident about
        depth[~(confidence >= min_confidence)] = np.nan
        return depth, confidence


def trusted_single_shot(
    depth: np.ndarray,
    image: np.ndarray,
    max_depth_step_mm: float = QualityLimits.max_depth_step_mm,
    fringes: np.ndarray | None = None,
    max_roughness_mm: float = np.inf,
) -> np.ndarray:
    """Set a network's depth to NaN (in place) where the image shows no usable fringes, where it
    smears a depth edge (a pixel whose depth differs from a neighbour's by more than max_depth_step_mm,
    the multi-shot path's flying-pixel rule: a network smooths a depth step across a few pixels), and,
    with a roughness limit, where the depth around it scatters by more than max_roughness_mm; the
    pixels kept then take their window's mean depth (local_depth)."""
    depth[~(fringe_mask(image) if fringes is None else fringes)] = np.nan
    depth[~drop_flying_pixels(depth, max_depth_step_mm)] = np.nan
    if np.isfinite(max_roughness_mm):
        mean, roughness = local_depth(depth)
        np.copyto(depth, mean)
        depth[~(roughness <= max_roughness_mm)] = np.nan
    return depth


def refusal_margin(depth: np.ndarray, fringes: np.ndarray, margin_px: int) -> None:
    """Set depth to NaN (in place) within margin_px pixels (a square) of a pixel that shows fringes but
    was given no depth. The network's errors are correlated over its receptive field, so a pixel the
    rules refused is evidence against its neighbours: on validation the wrong orders the rules let
    through sit beside refused pixels. A shadow (no fringes) is no such evidence."""
    if margin_px > 0:
        refused = (fringes & np.isnan(depth)).view(np.uint8)
        near = cv2.dilate(refused, np.ones((2 * margin_px + 1,) * 2, np.uint8))
        depth[near.view(bool)] = np.nan


ROUGHNESS_WINDOW = CONTRAST_WINDOW  # pixels: one period of the default rig's carrier


def local_depth(depth: np.ndarray, window: int = ROUGHNESS_WINDOW) -> tuple[np.ndarray, np.ndarray]:
    """(mean, roughness) of a single-shot depth map over the window around each pixel (mm, NaN where
    it has no depth; NaN pixels and the outside of the image left out).
    mean: one image tells the phase of a fringe period, not of a pixel (the window is one carrier
    period in the default rig), so the window's mean loses little the image holds and halves what the
    network's noise puts beyond 1 mm (on validation). Beside a hole or the border the window is
    lopsided and its mean is the depth at the known pixels' centroid, off by up to slope x 2 pixels
    on a tilted surface; on validation such pixels still come out nearer the truth than unsmoothed
    (a plane fit, unbiased there, measured about as good for three times the time: docs/single-shot.md).
    roughness: the RMS over the window of each depth's difference from its own window's mean: on a
    smooth surface, tilted or not, the network's phase noise through dz/dphi (a plane's depths equal
    their windows' means); where one image cannot tell the phase well (dark, noisy, textured,
    blurred) it grows, and a depth step in the window makes it large, so a mean across a step is never
    kept. It stands for the multi-shot path's expected depth noise; it understates the error (the
    network's errors are correlated over its receptive field), so its limit is chosen on validation."""
    known = np.isfinite(depth)
    if not known.any():
        return np.full(depth.shape, np.nan, np.float32), np.full(depth.shape, np.nan, np.float32)

    def window_sum(image, ddepth=-1):
        return cv2.boxFilter(image, ddepth, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)

    counts = window_sum(known.view(np.uint8), cv2.CV_32F)
    # OpenCV sums a float window in double precision: depths in mm keep float32's precision
    mean, squares = fused.window_mean_residuals(depth, window_sum(cv2.patchNaNs(depth.copy(), 0)), counts)
    roughness = fused.window_roughness(depth, mean, window_sum(squares), counts)
    return mean, roughness


def decoded_fringes(image: np.ndarray, out: np.ndarray, min_modulation: float, decoder) -> np.ndarray:
    """fringe_mask for a phase-aware network's outputs (its carrier's numerator and denominator first),
    with the carrier's share of the frame's contrast its decoder reads: the composite's, or the whole."""
    share = CARRIER_AMPLITUDE if isinstance(decoder, CompositeDecoder) else 1.0
    return fringe_mask(image, min_modulation, modulation=cv2.magnitude(out[0], out[1]), carrier_share=share)


def fringe_mask(
    image: np.ndarray,
    min_modulation: float = MIN_MODULATION,
    window: int = CONTRAST_WINDOW,
    modulation: np.ndarray | None = None,
    carrier_share: float = 1.0,
) -> np.ndarray:
    """Pixels of a single fringe image whose depth a network can know: the fringe modulation is at
    least min_modulation of full scale, and no pixel near it is saturated (clipped fringes). The image
    itself must show the contrast such a carrier makes (sqrt(2) x the local standard deviation over the
    window, the amplitude of one sinusoid, at least carrier_share x min_modulation: the composite's
    carrier has CARRIER_AMPLITUDE of the range), and where a phase-aware network estimates the
    multi-shot B (modulation, full-scale units: the multi-shot path's criterion) so must that: a
    network claims fringes where the image has none (at its borders in a black frame). A network
    answers everywhere; this keeps it from answering in shadows, in the dark and in glare."""
    scale = full_scale(image.dtype)
    mean = cv2.boxFilter(image, cv2.CV_32F, (window, window))
    variance = cv2.sqrBoxFilter(image, cv2.CV_32F, (window, window))
    variance -= cv2.multiply(mean, mean)
    ok = variance >= 0.5 * (carrier_share * min_modulation * scale) ** 2
    if modulation is not None:
        ok &= modulation >= min_modulation
    saturated = (image >= scale).astype(np.uint8)
    if saturated.any():
        ok &= cv2.dilate(saturated, np.ones((window, window), np.uint8)) == 0
    return ok
