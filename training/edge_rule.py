"""The single-shot path's edge rule, re-checked on validation data: the shipped composite network on
the composite set's validation split (never its test split), coverage of the exact depth's pixels and
silent errors (output pixels off by more than 1 mm) for each order-confidence threshold and each
flying-pixel step (trusted_single_shot drops a pixel more than STEP mm from a neighbour; the last
column is no edge rule).

    python -m training.edge_rule [--data data/fpp/composite]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from fpp_nodes.core.model import STRIDE, DepthModel, default_model_path, fringe_mask, network_input, trusted_single_shot

from .dataset import load_sample, split_files

CONFIDENCES = (0.5, 0.7, 0.8, 0.9, 0.95, 0.98)
STEPS_MM = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, np.inf)


def main():
    parser = argparse.ArgumentParser(
        prog="python -m training.edge_rule", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", default="data/fpp/composite")
    args = parser.parse_args()
    model = DepthModel(default_model_path())
    counts = {(c, s): np.zeros(3) for c in CONFIDENCES for s in STEPS_MM}  # output, silent, exact pixels
    files = split_files(args.data, "val")
    for f in files:
        image, _, truth = load_sample(f)
        x = network_input(image)
        h, w = x.shape
        padded = cv2.copyMakeBorder(x, 0, (-h) % STRIDE, 0, (-w) % STRIDE, cv2.BORDER_REPLICATE)
        out = model.session.run([model.output], {"image": padded[None, None]})[0][0, :, :h, :w]
        fringes = fringe_mask(image, modulation=np.hypot(out[0], out[1]))  # as DepthModel.infer
        for c in CONFIDENCES:
            depth = model.decoder(out, c, fringes)[0]
            for s in STEPS_MM:
                shown = trusted_single_shot(depth.copy(), image, max_depth_step_mm=s, fringes=fringes)
                ok = np.isfinite(shown) & np.isfinite(truth)
                counts[c, s] += (
                    ok.sum(),
                    np.count_nonzero(np.abs(shown[ok] - truth[ok]) > 1.0),
                    np.isfinite(truth).sum(),
                )
    print(f"{args.data} validation split, {len(files)} scenes; each cell: coverage, silent errors")
    print(f"{'confidence':>10} " + " ".join(f"{f'step {s:g} mm':>16}" for s in STEPS_MM))
    for c in CONFIDENCES:
        cells = (f"{n[0] / n[2]:7.1%} {n[1] / max(n[0], 1):7.2%}" for n in (counts[c, s] for s in STEPS_MM))
        print(f"{c:>10} " + " ".join(f"{cell:>16}" for cell in cells))


if __name__ == "__main__":
    main()
