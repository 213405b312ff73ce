"""What a single-shot model's error is made of: the RMSE of its output on a set's validation split,
by family, beside the multi-shot label's on its own pixels, in two tables:
- by the carrier's amplitude B (full scale = 1, from each sample's fringe targets): the camera's noise
  moves the phase by about its sigma / B;
- on the pixels with B >= 0.08, by the texture: the relative variation of B over one carrier period
  (9 x 9 pixels; its standard deviation over its mean), which one image cannot tell from a phase shift
  and four phase-shifted images cancel.
Each cell: the RMSE of the errors clipped at 1 mm (the phase, without the few pixels an order off),
then the share of the row's pixels in that range.

    PYTHONPATH=fpp_nodes:. python scripts/rmse_by_modulation.py [MODEL] [--data data/fpp/composite]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import yaml

from fpp_nodes.core.calibration import Calibration
from fpp_nodes.core.model import ROUGHNESS_WINDOW
from training.dataset import load_phase_targets, load_sample, split_files
from training.figures import load_models

AMPLITUDE_BINS = (0.0, 0.02, 0.04, 0.08, 0.16, 1.0)
TEXTURE_BINS = (0.0, 0.02, 0.05, 0.1, 0.2, np.inf)
BRIGHT = 0.08  # B at least this (full scale) for the texture table


def texture(amplitude: np.ndarray) -> np.ndarray:
    """The relative variation of the carrier's amplitude over one carrier period around each pixel."""
    window = (ROUGHNESS_WINDOW, ROUGHNESS_WINDOW)
    mean = cv2.blur(amplitude, window)
    spread = np.sqrt(np.maximum(cv2.blur(amplitude * amplitude, window) - mean * mean, 0.0))
    return spread / np.maximum(mean, 1e-6)


def add(totals: dict, key, error: np.ndarray, value: np.ndarray, bins) -> None:
    for i in range(len(bins) - 1):
        e = error[(value >= bins[i]) & (value < bins[i + 1])]
        t = totals.setdefault((*key, i), np.zeros(2))
        t += (e.size, float(np.square(np.minimum(np.abs(e), 1.0)).sum()))


def table(title: str, totals: dict, bins, names) -> None:
    print(title)
    print(f"{'family':10}{'':9}" + "".join(f"{n:>18}" for n in names))
    for family in sorted({k[1] for k in totals}):
        for source in ("network", "label"):
            counts = [totals[(source, family, i)] for i in range(len(bins) - 1)]
            n_all = max(sum(c[0] for c in counts), 1)
            cells = [f"{np.sqrt(s2 / n):.3f} {100 * n / n_all:4.1f}%" if n else "-" for n, s2 in counts]
            print(f"{family:10}{source:9}" + "".join(f"{c:>18}" for c in cells))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?", default="fpp_nodes/fpp_nodes/data/models/composite.onnx")
    parser.add_argument("--data", default="data/fpp/composite")
    parser.add_argument("--split", default="val")
    args = parser.parse_args(argv)
    info = yaml.safe_load((Path(args.data) / "dataset.yaml").read_text())
    ((_, model),) = load_models([args.model], Calibration.from_dict(info["calibration"]))
    by_amplitude, by_texture = {}, {}  # (source, family, bin) -> [pixels, sum of clipped squared errors]
    for f in split_files(args.data, args.split):
        image, label, truth = load_sample(f)
        if not np.isfinite(truth).any():
            raise SystemExit(f"{f} has no exact depth: this table needs a simulated set")
        fringe, _, family = load_phase_targets(f)
        amplitude = np.hypot(*fringe)
        variation = texture(amplitude)
        for source, depth in (("network", model.infer(image)[0]), ("label", label)):
            given = np.isfinite(depth) & np.isfinite(truth)
            error = (depth - truth)[given]
            add(by_amplitude, (source, family), error, amplitude[given], AMPLITUDE_BINS)
            bright = amplitude[given] >= BRIGHT
            add(by_texture, (source, family), error[bright], variation[given][bright], TEXTURE_BINS)
    table(
        f"{args.split} split of {args.data}: clipped RMSE mm by B",
        by_amplitude,
        AMPLITUDE_BINS,
        [f"B {a:.2f}-{b:.2f}" for a, b in zip(AMPLITUDE_BINS, AMPLITUDE_BINS[1:])],
    )
    table(
        f"pixels with B >= {BRIGHT}: by texture (B's variation over a period)",
        by_texture,
        TEXTURE_BINS,
        [f"{a:g}-{b:g}" for a, b in zip(TEXTURE_BINS, TEXTURE_BINS[1:])],
    )


if __name__ == "__main__":
    main()
