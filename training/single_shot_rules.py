"""The single-shot path's pixel rules, re-checked on validation data: the shipped composite network on
the composite set's validation split (never its test split). Each cell: coverage of the exact depth's
pixels, and silent errors (output pixels off by more than 1 mm); in the margin's table also wrong
orders (off by more than half a fringe order: wrong_order_mm). Five tables, each against the
order-confidence threshold, the other rules as the shipped card has them:
- the edge rule's step (trusted_single_shot drops a pixel more than STEP mm from a neighbour; inf: no
  rule);
- the fringe mask's floor (fringe_mask: the network's fringe modulation, a fraction of full scale);
- the decoder's smallest surface whose vote counts (CompositeDecoder.min_surface_px);
- the roughness limit (trusted_single_shot drops a pixel whose neighbourhood's depth scatters more);
- the refusal margin (refusal_margin drops the pixels this near a pixel refused where fringes show).

    python -m training.single_shot_rules [--data data/fpp/composite]
"""

from __future__ import annotations

import argparse

import numpy as np

from fpp_nodes.core.model import DepthModel, default_model_path
from fpp_nodes.core.reconstruct import QualityLimits
from fpp_nodes.core.workflow import wrong_order_mm

from .dataset import load_sample, sample_family, split_files
from .export import FLOOR_GRID, MARGIN_GRID, ROUGHNESS_GRID, SURFACE_GRID, rule_counts, rule_rates

CONFIDENCES = (0.5, 0.7, 0.75, 0.8, 0.82, 0.84, 0.86, 0.88, 0.9, 0.92, 0.95)
STEPS_MM = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, np.inf)
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
    outputs = []  # (image, exact depth, network outputs, family), run once
    for f in files:
        image, _, truth = load_sample(f)
        outputs.append((image, truth, model.outputs(image), sample_family(f)))
    floor, surface, rough, margin = (
        model.min_modulation,
        model.decoder.min_surface_px,
        model.max_roughness_mm,
        model.margin_px,
    )
    shipped = dict(
        floors=(floor,),
        surfaces_px=(surface,),
        sidebands=(model.max_sideband,),
        outside=(model.max_outside,),
        roughness_mm=(rough,),
        margins_px=(margin,),
        wrong_order=wrong_order_mm(model.card_calibration),
    )

    def count(**varied):
        more = rule_counts(outputs, model.decoder, confidences=CONFIDENCES, **(shipped | varied))
        counts.update({(m, px, c, s, r, k): n for (m, px, _, _, c, s, r, k), n in more.items()})  # one of each refusal

    counts = {}
    count(steps_mm=STEPS_MM)
    count(floors=FLOOR_GRID)
    count(surfaces_px=SURFACE_GRID)
    count(roughness_mm=ROUGHNESS_GRID)
    count(margins_px=MARGIN_GRID)
    print(f"{args.data} validation split, {len(files)} scenes; each cell: coverage, silent errors")
    table("edge rule step", [(f"step {s:g} mm", (floor, surface, s, rough, margin)) for s in STEPS_MM], counts)
    table("fringe mask floor", [(f"floor {m:g}", (m, surface, STEP, rough, margin)) for m in FLOOR_GRID], counts)
    table("smallest surface", [(f"surface {px} px", (floor, px, STEP, rough, margin)) for px in SURFACE_GRID], counts)
    table(
        "roughness limit", [(f"roughness {x:g} mm", (floor, surface, STEP, x, margin)) for x in ROUGHNESS_GRID], counts
    )
    table("refusal margin", [(f"margin {k} px", (floor, surface, STEP, rough, k)) for k in MARGIN_GRID], counts, True)


def table(title: str, columns: list, counts: dict, orders: bool = False) -> None:
    width = 24 if orders else 16
    print(f"\n{title}\n{'confidence':>10} " + " ".join(f"{name:>{width}}" for name, _ in columns))
    for c in CONFIDENCES:
        cells = []
        for _, (floor, surface, step, rough, margin) in columns:
            r = rule_rates(counts[floor, surface, c, step, rough, margin])
            cells.append(
                f"{r['coverage']:7.1%} {r['silent_errors']:7.2%}" + (f" {r['wrong_orders']:7.3%}" if orders else "")
            )
        print(f"{c:>10} " + " ".join(f"{cell:>{width}}" for cell in cells))


if __name__ == "__main__":
    main()
