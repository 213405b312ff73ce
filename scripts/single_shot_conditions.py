"""The shipped single-shot model (or --model) on a rig whose photometry leaves the ranges it was trained
on (training's `random_rig`: ambient 0-15% of full scale, gain 0.4-1.0, noise 0.5-3 counts, blur 0.3-1.2
px; the projector's gamma as the patterns assume): does it say NaN, or guess?

Renders the same scenes (the demo's sculpture and fresh seeds of three training families, none in any
data set) under each condition with the default rig's geometry and prints the coverage of the lit
pixels and the share of the output off the exact depth by more than 1 and 4 mm.

    python scripts/single_shot_conditions.py
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.model import DepthModel, default_model_path
from fpp_nodes.core.scenes import make_scene
from fpp_nodes.core.simulation import Rig, render

CONDITIONS = {
    "inside the training ranges (default rig)": {},
    "ambient 30% of full scale": dict(ambient=0.3),
    "gain 0.2 (dark)": dict(gain=0.2),
    "gain 0.2 and noise 3 counts": dict(gain=0.2, noise_sigma=3.0),
    "noise 5 counts": dict(noise_sigma=5.0),
    "defocus 2 px": dict(blur_sigma_px=2.0),
    "defocus 3 px": dict(blur_sigma_px=3.0),
    "projector gamma 2.6, patterns for 2.2": dict(projector_gamma=2.6),
    "projector gamma 1.8, patterns for 2.2": dict(projector_gamma=1.8),
    "gain 1.3 (bright surfaces clip)": dict(gain=1.3),
}
SCENES = [(family, seed) for family in ("sculpture", "freeform", "blocks", "bust") for seed in (7001, 7002)]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=default_model_path())
    args = parser.parse_args(argv)
    base = Rig()
    patterns = base.pattern_set()  # pre-compensated for the default gamma, whatever the projector's is
    model = DepthModel(args.model)
    print(f"{len(SCENES)} scenes (the sculpture and fresh seeds of freeform, blocks, bust), {args.model}")
    print(f"{'condition':40} {'cover':>6} {'>1mm':>6} {'>4mm':>7}")
    for name, changes in CONDITIONS.items():
        rig = replace(base, **changes)
        within, beyond = ErrorTotals(), ErrorTotals()
        for family, seed in SCENES:
            capture = render(rig, make_scene(rig, family, seed), patterns, np.random.default_rng(seed))
            truth = np.where(capture.valid, capture.depth_mm, np.nan)
            depth = model(capture.images[patterns.single_shot_index])
            within.add(depth, truth, 1.0)
            beyond.add(depth, truth, 4.0)
        print(f"{name:40} {within.coverage:6.1%} {within.share_over:6.2%} {beyond.share_over:7.3%}")
    print("cover: share of lit pixels given a depth; >1mm, >4mm: share of those off the exact depth by more")


if __name__ == "__main__":
    main()
