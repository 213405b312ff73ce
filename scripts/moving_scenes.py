"""Scenes that move while the sensor looks: does each path say NaN, or guess?

    source scripts/env.bash && python scripts/moving_scenes.py [--model M]

Two held-out scenes (offline demo's: a sculpture and separated objects, seeds 1000 and 1001) under the
default rig, moving as a whole across the image (along the fringes' phase, x, or along them, y) or
toward the camera (z):
- the multi-shot path sees the scene move by a given amount from one frame of its sequence to the
  next (each frame itself sharp), and decodes the 16 phase-shift frames through a calibration from
  simulated planes (as `fpp demo` does);
- the single-shot path sees it move by a given amount during its one exposure: the frame is the mean
  of noise-free frames of the scene at every whole-pixel step of the way (every 0.25 mm of z), then
  the camera's noise.
The truth is the scene at the middle of the highest frequency's four frames (their phase is the
multi-shot depth, the lower frequencies give its order; the cloud is stamped with the sequence's first
frame, 12.5 frames before) or of the exposure. A pixel a moving edge crosses has no
single depth to be measured; the table counts every lit pixel. Prints, per path and motion, the share
of the lit pixels given a depth, of those off by more than 1 mm, and off by more than half a fringe
order (a wrong order). One pixel is about 0.24 mm on the default rig's surfaces at 1.2 m; at 30 camera
frames/s a pixel a frame is 7 mm/s.
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.model import DepthModel, default_model_path
from fpp_nodes.core.patterns import pattern_images
from fpp_nodes.core.reconstruct import PspReconstructor
from fpp_nodes.core.simulation import Rig, Scene, SceneRenderer
from fpp_nodes.core.workflow import held_out_scenes, simulated_calibration, wrong_order_mm

SEQUENCE_MOTION = {"x": (0.1, 0.25, 0.5, 1, 2), "y": (0.5, 2), "z": (0.01, 0.05, 0.2)}  # px or mm a frame
EXPOSURE_MOTION = {"x": (2, 4, 8, 16), "y": (4, 16), "z": (1.0, 3.0)}  # px or mm during the exposure
Z_STEP_MM = 0.25  # the single-shot exposure's frames along z


def moved(scene: Scene, axis: str, amount: float) -> Scene:
    """The scene moved by amount: px across the image (x, y; rounded to whole pixels, the newly seen
    border filled with its nearest row or column), or mm away from the camera (z)."""
    if axis == "z":
        return Scene(scene.name, scene.depth_mm + amount, scene.albedo)
    shift = [0.0, 0.0]
    shift["xy".index(axis)] = float(round(amount))
    move = np.float64([[1, 0, shift[0]], [0, 1, shift[1]]])
    size = scene.depth_mm.shape[::-1]
    return Scene(
        scene.name,
        *(
            cv2.warpAffine(a, move, size, flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
            for a in (scene.depth_mm, scene.albedo)
        ),
    )


class Renders:
    """Renderers of one scene's moves, each made once (the geometry is most of a render's time)."""

    def __init__(self, rig: Rig, scene: Scene):
        self.rig, self.scene, self.made = rig, scene, {}

    def __call__(self, axis: str, amount: float) -> SceneRenderer:
        key = (axis, round(amount, 4) if axis == "z" else int(round(amount)))
        if key not in self.made:
            self.made[key] = SceneRenderer(self.rig, moved(self.scene, axis, amount))
        return self.made[key]


def truth(renderer: SceneRenderer) -> np.ndarray:
    t = renderer.truth()
    return np.where(t.valid, t.depth_mm, np.nan)


def sequence(renders: Renders, patterns, axis: str, per_frame: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """The pattern set's frames with the scene moved by per_frame between frames, and the truth at the
    middle of the highest frequency's frames (their phase is the depth; the lower ones give its order)."""
    frames = pattern_images(patterns)
    middle = (len(patterns.frequencies) - 0.5) * patterns.steps - 0.5  # 13.5 of frames 0-16
    images = [renders(axis, per_frame * (k - middle)).image(f, patterns.max_value, rng) for k, f in enumerate(frames)]
    return np.stack(images), truth(renders(axis, 0.0))


def exposure(renders: Renders, patterns, axis: str, during: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """The single-shot frame with the scene moved by during over the exposure, and the truth at its middle."""
    frame = pattern_images(patterns)[patterns.single_shot_index]
    steps = max(int(round(during / (Z_STEP_MM if axis == "z" else 1.0))), 1)
    offsets = np.linspace(-during / 2, during / 2, steps + 1) if during else [0.0]
    mean = np.mean([renders(axis, o).image(frame, patterns.max_value, None).astype(np.float32) for o in offsets], 0)
    rig = renders.rig
    noisy = mean + rig.noise_sigma * rng.standard_normal(mean.shape, dtype=np.float32)
    return np.clip(np.rint(noisy), 0, rig.full_scale).astype(np.uint8), truth(renders(axis, 0.0))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=default_model_path())
    args = parser.parse_args()
    rig = Rig()
    patterns = rig.pattern_set()
    calibration, _ = simulated_calibration(rig, patterns, seed=0)
    psp, model = PspReconstructor(calibration), DepthModel(args.model)
    order_mm = wrong_order_mm(calibration)
    scenes = [Renders(rig, scene) for _, scene, _ in held_out_scenes(rig, 2)]
    unit = {"x": "px", "y": "px", "z": "mm"}
    rows = []
    for path, motions, run in (
        ("multi-shot", SEQUENCE_MOTION, lambda images: psp(images).depth_mm),
        ("single-shot", EXPOSURE_MOTION, model),
    ):
        take = sequence if path == "multi-shot" else exposure
        for axis, amount in [("x", 0.0)] + [(a, m) for a, ms in motions.items() for m in ms]:
            over, orders = ErrorTotals(), ErrorTotals()
            for i, renders in enumerate(scenes):
                image, exact = take(renders, patterns, axis, amount, np.random.default_rng(i))
                depth = run(image)
                over.add(depth, exact, 1.0)
                orders.add(depth, exact, order_mm)
            when = "a frame" if path == "multi-shot" else "in the exposure"
            motion = "still" if amount == 0 else f"{axis} {amount:g} {unit[axis]} {when}"
            rows.append((path, motion, over.coverage, over.share_over, orders.share_over))
    print(f"{'path':12} {'motion':28} {'cover':>7} {'>1mm':>7} {'orders':>8}")
    for path, motion, cover, silent, wrong in rows:
        print(f"{path:12} {motion:28} {cover:7.1%} {silent:7.2%} {wrong:8.3%}")
    print(
        "cover: share of the lit pixels (at the middle of the motion) given a depth; >1mm, orders: share of those off "
        f"by more than 1 mm and by more than half a fringe order ({order_mm:.1f} mm)"
    )


if __name__ == "__main__":
    main()
