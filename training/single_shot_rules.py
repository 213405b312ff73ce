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

import numpy as np

from fpp_nodes.core.model import MIN_MODULATION, DepthModel, default_model_path
from fpp_nodes.core.reconstruct import QualityLimits

from .dataset import load_sample, split_files
from .export import rule_counts

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
    files = split_files(args.data, "val")
    outputs = []  # (image, exact depth, network outputs), run once
    for f in files:
        image, _, truth = load_sample(f)
        outputs.append((image, truth, model.outputs(image)))
    counts = rule_counts(outputs, model.decoder, (MIN_MODULATION,), CONFIDENCES, STEPS_MM)
    counts.update(rule_counts(outputs, model.decoder, FLOORS, CONFIDENCES))
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
