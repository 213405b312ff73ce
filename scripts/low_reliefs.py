"""Low reliefs through the single-shot path: a plane at the stand-off covered with 20 mm squares
(40 mm apart) raised or engraved by 1.5-6 mm, rendered by the default rig (plane_scene's plain
albedo, 0.9), each model's share of the lit pixels given a depth, of its output off by more than 1 mm,
and the 99.9th percentile of its error (mm).

    source scripts/env.bash && python scripts/low_reliefs.py [MODEL.onnx ...]   # default: the shipped

A step under half a fringe order (4.7 mm in the default rig) leaves the absolute phase continuous,
so the decoder sees no step; the network smooths it over a few pixels and the window's mean over a
few more: the pixels beside the edges are up to 1.4-2.5 mm off at steps of 2.5-4.5 mm, and no rule
refuses them. From about half an order the phase steps by more than pi and the edges are refused
(docs/single-shot.md, the working volume).
"""

from __future__ import annotations

import argparse

import numpy as np

from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.model import DepthModel, default_model_path
from fpp_nodes.core.scenes import plane_scene
from fpp_nodes.core.simulation import Rig, Scene, render

STEPS_MM = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 6.0)


def relief(rig: Rig, step_mm: float) -> Scene:
    """Squares 20 mm wide on a 40 mm pitch, step_mm nearer than the plane at the stand-off (negative:
    engraved), as seen on the plane."""
    plane = plane_scene(rig, rig.standoff_mm)
    x, y = rig.camera().rays()
    squares = (np.mod(x * rig.standoff_mm, 40) < 20) & (np.mod(y * rig.standoff_mm, 40) < 20)
    return Scene(f"relief {step_mm:+g} mm", plane.depth_mm - np.where(squares, step_mm, 0.0), plane.albedo)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", nargs="*", default=[default_model_path()])
    args = parser.parse_args()
    rig = Rig()
    patterns = rig.pattern_set()
    models = [DepthModel(p) for p in args.models]
    print(f"{'squares':>18}" + "".join(f"{p.rsplit('/', 1)[-1][-24:]:>26}" for p in args.models))
    print(f"{'':>18}" + f"{'cover   >1mm   p99.9':>26}" * len(models))
    for step in STEPS_MM:
        for sign, name in ((1, "raised"), (-1, "engraved")):
            capture = render(rig, relief(rig, sign * step), patterns, np.random.default_rng(int(step * 10)))
            truth = np.where(capture.valid, capture.depth_mm, np.nan)
            image = capture.images[patterns.single_shot_index]
            cells = []
            for model in models:
                depth = model(image)
                totals = ErrorTotals().add(depth, truth, 1.0)
                worst = np.nanpercentile(np.abs(depth - truth), 99.9)
                cells.append(f"{totals.coverage:7.1%} {totals.share_over:6.2%} {worst:7.2f}")
            print(f"{name:>9} {step:4.1f} mm" + "".join(f"{c:>26}" for c in cells))
    print(
        "cover: share of the lit pixels given a depth; >1mm: share of those off by more than 1 mm (silent errors); "
        "p99.9: the 99.9th percentile of their error, mm"
    )


if __name__ == "__main__":
    main()
