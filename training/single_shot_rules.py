"""The single-shot path's pixel rules, re-checked on validation data: the shipped composite network on
the composite set's validation split (never its test split). Each cell: coverage of the exact depth's
pixels, and silent errors (output pixels off by more than 1 mm). Two tables, each against the
order-confidence threshold:
- the edge rule's step (trusted_single_shot drops a pixel more than STEP mm from a neighbour; inf: no
  rule), with the fringe mask's floor at MIN_MODULATION;
- the fringe mask's floor (fringe_mask: the network's fringe modulation, a fraction of full scale),
  with the 2 mm edge rule.

    python -m training.single_shot_rules [--data data/fpp/composite]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from fpp_nodes.core.model import (
    MIN_MODULATION,
    STRIDE,
    DepthModel,
    default_model_path,
    fringe_mask,
    network_input,
    trusted_single_shot,
)
from fpp_nodes.core.reconstruct import QualityLimits

from .dataset import load_sample, split_files

CONFIDENCES = (0.5, 0.7, 0.8, 0.9, 0.92, 0.94, 0.95, 0.98)
STEPS_MM = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, np.inf)
FLOORS = (0.01, 0.02, 0.03, MIN_MODULATION)
STEP = QualityLimits.max_depth_step_mm


def main():
    parser = argparse.ArgumentParser(
        prog="python -m training.single_shot_rules",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--data", default="data/fpp/composite")
    args = parser.parse_args()
    model = DepthModel(default_model_path())
    counts = {}  # (floor, confidence, step) -> output, silent, exact pixels
    files = split_files(args.data, "val")
    for f in files:
        image, _, truth = load_sample(f)
        x = network_input(image)
        h, w = x.shape
        padded = cv2.copyMakeBorder(x, 0, (-h) % STRIDE, 0, (-w) % STRIDE, cv2.BORDER_REPLICATE)
        out = model.session.run([model.output], {"image": padded[None, None]})[0][0, :, :h, :w]
        for floor in FLOORS:  # as DepthModel.infer, at each floor
            fringes = fringe_mask(image, min_modulation=floor, modulation=np.hypot(out[0], out[1]))
            for c in CONFIDENCES:
                depth = model.decoder(out, c, fringes)[0]
                for s in STEPS_MM if floor == MIN_MODULATION else (STEP,):
                    shown = trusted_single_shot(depth.copy(), image, max_depth_step_mm=s, fringes=fringes)
                    ok = np.isfinite(shown) & np.isfinite(truth)
                    silent = np.count_nonzero(np.abs(shown[ok] - truth[ok]) > 1.0)
                    cell = counts.setdefault((floor, c, s), np.zeros(3))
                    cell += (ok.sum(), silent, np.isfinite(truth).sum())
    print(f"{args.data} validation split, {len(files)} scenes; each cell: coverage, silent errors")
    table("edge rule step", [(f"step {s:g} mm", (MIN_MODULATION, s)) for s in STEPS_MM], counts)
    table("fringe mask floor", [(f"floor {m:g}", (m, STEP)) for m in FLOORS], counts)


def table(title: str, columns: list, counts: dict) -> None:
    print(f"\n{title}\n{'confidence':>10} " + " ".join(f"{name:>16}" for name, _ in columns))
    for c in CONFIDENCES:
        cells = []
        for _, (floor, step) in columns:
            n = counts[floor, c, step]
            cells.append(f"{n[0] / n[2]:7.1%} {n[1] / max(n[0], 1):7.2%}")
        print(f"{c:>10} " + " ".join(f"{cell:>16}" for cell in cells))


if __name__ == "__main__":
    main()
