"""The range rule's threshold for the classical single-shot baseline (FTP on the composite): as export
chooses a network's (training/export.py, OUTSIDE_GRID and OUTSIDE_REFUSAL_BUDGET), the lowest max_outside
that refuses at most the budget of FTP's output on a set's validation scenes, every surface of which lies
in the working range, so what the rule refuses there is its false alarms. Prints the share each threshold
refuses and the choice. On the composite set none is within the budget (FTP's codes are noisier than
the network's), so `fpp reconstruct --method ftp` has no range rule, only the warning.

    PYTHONPATH=fpp_nodes:. python scripts/ftp_range_rule.py [--data data/fpp/composite] [--limit 200]
"""

from __future__ import annotations

import argparse

import numpy as np

from fpp_nodes.core.reconstruct import CompositeDecoder, reconstruct_ftp
from training.dataset import load_sample, sets_calibration, split_files
from training.export import OUTSIDE_GRID, OUTSIDE_REFUSAL_BUDGET, lowest_within


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default="data/fpp/composite")
    parser.add_argument("--limit", type=int, default=200)
    args = parser.parse_args(argv)
    calibration = sets_calibration([args.data])
    thresholds = (*OUTSIDE_GRID, np.inf)
    decoders = {t: CompositeDecoder(calibration, max_outside=t) for t in thresholds}
    output = dict.fromkeys(thresholds, 0)
    files = split_files(args.data, "val")[: args.limit]
    for f in files:
        image = load_sample(f)[0]
        for t, decoder in decoders.items():
            output[t] += np.count_nonzero(np.isfinite(reconstruct_ftp(image, calibration, decoder=decoder).depth_mm))
    print(f"FTP on {len(files)} validation scenes of {args.data}: the share of its output each max_outside refuses")
    lowest, refused = lowest_within(output, OUTSIDE_GRID, OUTSIDE_REFUSAL_BUDGET)
    for t, share in refused.items():
        print(f"  {t:5g}  {share:.6f}")
    print(f"chosen (the lowest within {OUTSIDE_REFUSAL_BUDGET:g}): {lowest:g}")


if __name__ == "__main__":
    main()
