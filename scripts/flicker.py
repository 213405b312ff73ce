"""The multi-shot path when the light changes from frame to frame of a sequence (a lamp's flicker, an
exposure or gain the camera adjusts on its own): does it say NaN, or guess?

    source scripts/env.bash && python scripts/flicker.py

Two held-out scenes (`fpp demo`'s sculpture and separated objects) under the default rig, each frame's
projected light scaled by 1 + s g with g drawn from a standard normal per frame (the ambient light
stays), then the camera's noise; decoded through a calibration from simulated planes. Phase shifting
takes the four images of a frequency to differ only by the pattern's shift, so a changing brightness
reads as phase error. Prints, per s, the share of the lit pixels given a depth, the RMSE against the
exact depth, and the shares off by more than 1 mm and by more than half a fringe order.
"""

from __future__ import annotations

import numpy as np

from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.patterns import pattern_images
from fpp_nodes.core.reconstruct import PspReconstructor
from fpp_nodes.core.simulation import Rig, SceneRenderer
from fpp_nodes.core.workflow import held_out_scenes, simulated_calibration, wrong_order_mm

FLICKER = (0.0, 0.005, 0.01, 0.02, 0.05, 0.1)  # standard deviation of each frame's brightness


def main():
    rig = Rig()
    patterns = rig.pattern_set()
    calibration, _ = simulated_calibration(rig, patterns, seed=0)
    psp, order_mm = PspReconstructor(calibration), wrong_order_mm(calibration)
    ambient = rig.full_scale * rig.ambient
    scenes = []
    for _, scene, _ in held_out_scenes(rig, 2):
        renderer = SceneRenderer(rig, scene)
        clean = np.stack([renderer.image(f, patterns.max_value, None) for f in pattern_images(patterns)])
        exact = renderer.truth()
        scenes.append((clean.astype(np.float32) - ambient, np.where(exact.valid, exact.depth_mm, np.nan)))
    print(f"{'flicker':>8} {'cover':>7} {'RMSE mm':>8} {'>1mm':>7} {'orders':>7}")
    for flicker in FLICKER:
        over, orders = ErrorTotals(), ErrorTotals()
        for i, (lit, exact) in enumerate(scenes):
            rng = np.random.default_rng(100 + i)
            gain = 1 + flicker * rng.standard_normal(len(lit)).astype(np.float32)
            level = lit * gain[:, None, None] + ambient + rig.noise_sigma * rng.standard_normal(lit.shape, np.float32)
            depth = psp(np.clip(np.rint(level), 0, rig.full_scale).astype(np.uint8)).depth_mm
            over.add(depth, exact, 1.0)
            orders.add(depth, exact, order_mm)
        print(f"{flicker:8.1%} {over.coverage:7.1%} {over.rmse:8.4f} {over.share_over:7.2%} {orders.share_over:7.3%}")
    print(
        "flicker: standard deviation of each frame's brightness; cover: share of the lit pixels given a depth; "
        f">1mm, orders: share of those off by more than 1 mm and by more than half a fringe order ({order_mm:.1f} mm)"
    )


if __name__ == "__main__":
    main()
