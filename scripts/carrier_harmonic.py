"""Where a single-shot model's silent errors sit, by the image's second harmonic of the carrier.

An albedo multiplies the projected light: its component at the carrier's own frequency, times the
light's mean, shifts the carrier's phase (one image cannot tell that from depth), and times the carrier
it makes a second harmonic, which sinusoidal light makes only through a gamma error. So the second
harmonic's amplitude against the carrier's (the image demodulated at the network's carrier phase and at
twice it, over a Gaussian window) measures the albedo content that corrupts the phase. Prints, over the
model's output on a set's validation split (after all its rules), the share of the output in each range
of that ratio, the share of it off the exact depth by more than 1 mm, and its share of all such errors.

    PYTHONPATH=fpp_nodes:. python scripts/carrier_harmonic.py [MODEL] [--data data/fpp/composite]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from fpp_nodes.core.model import DepthModel, default_model_path
from training.dataset import load_sample, split_files

RATIO_BINS = (0.0, 0.05, 0.1, 0.2, 0.3, 0.6, np.inf)
WINDOW_SIGMA_PX = 9.0  # one carrier period of the default rig


def harmonic_ratio(image: np.ndarray, carrier_phase: np.ndarray) -> np.ndarray:
    """|second harmonic| / |first| of the image at the carrier's phase, over the window around each pixel."""
    image = image.astype(np.float32)

    def amplitude(k):
        parts = (cv2.GaussianBlur(image * f(k * carrier_phase), (0, 0), WINDOW_SIGMA_PX) for f in (np.cos, np.sin))
        return cv2.magnitude(*parts)

    return amplitude(2) / np.maximum(amplitude(1), 1e-6)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?", default=default_model_path())
    parser.add_argument("--data", default="data/fpp/composite")
    args = parser.parse_args(argv)
    model = DepthModel(args.model)
    given, wrong = np.zeros(len(RATIO_BINS) - 1), np.zeros(len(RATIO_BINS) - 1)
    files = split_files(args.data, "val")
    for path in files:
        image, _, truth = load_sample(path)
        out = model.outputs(image)
        depth, _ = model.decode(image, out)
        ratio = harmonic_ratio(image, np.arctan2(out[0], out[1]))
        kept = np.isfinite(depth) & np.isfinite(truth)
        off = kept & (np.abs(depth - truth) > 1.0)
        for counts, where in ((given, kept), (wrong, off)):
            counts += np.histogram(ratio[where], RATIO_BINS)[0]
    print(f"{len(files)} validation scenes of {args.data}, {args.model}")
    print("2nd/1st harmonic   share of the output   off by more than 1 mm   share of the silent errors")
    for low, high, n, bad in zip(RATIO_BINS[:-1], RATIO_BINS[1:], given, wrong):
        span = f"{low:.2f}-{high:.2f}" if np.isfinite(high) else f"{low:.2f}-"
        print(f"{span:14} {n / given.sum():17.1%} {bad / max(n, 1):21.3%} {bad / max(wrong.sum(), 1):26.1%}")


if __name__ == "__main__":
    main()
