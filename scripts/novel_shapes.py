"""Both paths on shapes no scene family draws: height maps on the background plane at the stand-off,
rendered by the default rig (plane_scene's plain albedo, 0.9; or --blur PX for the camera), each
path's share of the lit pixels given a depth, of its output off by more than 1 mm (silent errors) and
by more than half a fringe order (4.7 mm), and its RMSE against the exact depth; the output counts
wherever it is, in the projector's shadows too (the data sets' tables leave those pixels out).

    source scripts/env.bash && python scripts/novel_shapes.py [--blur PX] [--model MODEL.onnx]

The shapes were written to try the sensor as a user would, after the families were fixed; no rule or
threshold was chosen on them. The staircase is the low steps that face away from the projector
(docs/multi-shot.md, low steps under defocus).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fpp_nodes"))
from fpp_nodes.core.calibration import Calibration, default_calibration_path  # noqa: E402
from fpp_nodes.core.metrics import ErrorTotals  # noqa: E402
from fpp_nodes.core.model import DepthModel, default_model_path  # noqa: E402
from fpp_nodes.core.reconstruct import PspReconstructor  # noqa: E402
from fpp_nodes.core.scenes import plane_scene  # noqa: E402
from fpp_nodes.core.simulation import Rig, Scene, render  # noqa: E402

HALF_ORDER_MM = 4.7  # half a fringe order's depth in the default rig


def heights(rig: Rig) -> dict[str, np.ndarray]:
    """Height (mm, towards the camera) above the plane at the stand-off, per camera pixel."""
    x, y = (r * rig.standoff_mm for r in rig.camera().rays())
    radius = np.hypot(x, y)
    bumps = np.zeros_like(x)
    rng = np.random.default_rng(7)
    for _ in range(60):
        cx, cy, size = rng.uniform(-70, 70), rng.uniform(-50, 50), rng.uniform(3, 8)
        bumps += rng.uniform(2, 8) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * size**2))
    block = (np.abs(x) < 45) & (np.abs(y) < 40)
    return {
        "torus lying": np.sqrt(np.clip(12**2 - (radius - 35) ** 2, 0, None)),
        "corrugated sheet": 20 + 8 * np.sin(2 * np.pi * x / 50),
        "bowl in a block": np.where(block, 60 - np.minimum(np.sqrt(np.clip(38**2 - radius**2, 0, None)), 45), 0),
        "pyramid": np.clip(50 - 50 / 40 * np.maximum(np.abs(x), np.abs(y)), 0, None),
        "staircase 4 mm": np.where(np.abs(y) < 45, np.clip(np.floor((x + 60) / 10), 0, 12) * 4, 0),
        "wedge": np.where((x > -40) & (x < 20) & (np.abs(y) < 35), x + 40, 0),
        "post 90 mm": np.where(radius < 15, 90.0, 0.0),
        "cup wall": np.where((radius < 30) & (radius > 25), 50.0, 0.0),
        "crumpled sheet": bumps + 10,
        "plane at 40 deg": 50 + np.tan(np.radians(40)) * x,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--blur", type=float, default=Rig.blur_sigma_px, help="the camera's blur, px")
    parser.add_argument("--model", default=default_model_path(), help="the single-shot model")
    args = parser.parse_args()
    rig = replace(Rig(), blur_sigma_px=args.blur)
    patterns = rig.pattern_set()
    psp, model = PspReconstructor(Calibration.load(default_calibration_path())), DepthModel(args.model)
    plane = plane_scene(rig, rig.standoff_mm)
    print(f"camera blur {args.blur:g} px; model {args.model}")
    print(f"{'shape':18}" + f"{'multi-shot':>34}{'single-shot':>34}")
    print(f"{'':18}" + f"{'cover   >1mm  orders   RMSE':>34}" * 2)
    for name, height in heights(rig).items():
        scene = Scene(name, plane.depth_mm - height, plane.albedo)
        capture = render(rig, scene, patterns, np.random.default_rng(11))
        lit = np.where(capture.valid, capture.depth_mm, np.nan)
        depths = (psp(capture.images).depth_mm, model(capture.images[patterns.single_shot_index]))
        cells = []
        for depth in depths:
            # errors over all the output, the projector's shadows too: a robot uses depth given there
            silent, orders = (ErrorTotals().add(depth, capture.depth_mm, bound) for bound in (1.0, HALF_ORDER_MM))
            cover = ErrorTotals().add(depth, lit).coverage
            cells.append(f"{cover:7.1%} {silent.share_over:6.2%} {orders.share_over:7.3%} {silent.rmse:6.3f}")
        print(f"{name:18}" + "".join(f"{c:>34}" for c in cells))
    print(
        "cover: share of the lit pixels given a depth; >1mm, orders: share of the output off by more than 1 mm "
        f"and by more than half a fringe order ({HALF_ORDER_MM} mm); RMSE mm against the exact depth"
    )


if __name__ == "__main__":
    main()
