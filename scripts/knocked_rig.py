"""Both paths on a rig knocked since its calibration: the projector rolled about its axis, or moved up or down,
after calibrating. Each scene is rendered by the knocked rig and decoded through the calibration of the rig as it
was (the shipped model's card). The single-shot path with the rig-misfit rule (DepthModel.max_misfit_rad: the
frame is refused where the codes miss the orders named smoothly over it, CompositeDecoder.misfit_of) and without
it; the multi-shot path's own check (fpp_depth: reconstruct.CodeFit, the composite frame's codes by FTP against
the multi-shot depth, a warning beyond MAX_CODE_MISFIT_RAD) and its depth's median error. Then the single-shot
misfit of a data set's validation frames, every one from the rig as calibrated: the rule's false alarms.

    python scripts/knocked_rig.py [--seed S] [--data data/fpp/composite]

Prints per knock the single-shot misfit of its frames, the frames refused, and the lit pixels given a depth and
the share of those off the exact depth by more than 1 mm, with the rule and without; without it also the share
off by more than 0.25 mm (a knock too small to put orders wrong still moves the depth); then the multi-shot
path's code misfit, the frames it warns of, and its depth's median error; and the multi-shot check on fresh
scenes of every scene family under the training's random photometry, as calibrated (its false alarms).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.model import DepthModel, default_model_path
from fpp_nodes.core.reconstruct import MAX_CODE_MISFIT_RAD, CodeFit, PspReconstructor
from fpp_nodes.core.scenes import FAMILY_NAMES, make_scene
from fpp_nodes.core.simulation import Rig, random_rig, render
from training.dataset import load_sample, split_files

KNOCKS = {
    "as calibrated": {},
    "projector rolled 0.05 degree": dict(projector_roll_deg=0.05),
    "projector rolled 0.1 degree": dict(projector_roll_deg=0.1),
    "projector rolled 0.2 degree": dict(projector_roll_deg=0.2),
    "projector rolled 0.3 degree": dict(projector_roll_deg=0.3),
    "projector rolled 0.5 degree": dict(projector_roll_deg=0.5),
    "projector 10 mm lower": dict(projector_below_mm=10.0),
    "projector 20 mm lower": dict(projector_below_mm=20.0),
    "projector 10 mm higher": dict(projector_below_mm=-10.0),
    "projector 20 mm higher": dict(projector_below_mm=-20.0),
}
FAMILIES = ("sculpture", "objects")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=default_model_path())
    parser.add_argument("--seed", type=int, default=7001, help="scenes of seeds seed and seed + 1 of each family")
    parser.add_argument("--data", default="data/fpp/composite", help="a set whose validation frames to read")
    args = parser.parse_args(argv)
    ruled, unruled = DepthModel(args.model), DepthModel(args.model)
    unruled.max_misfit_rad = np.inf
    base = Rig()
    patterns = base.pattern_set()
    scenes = [(family, args.seed + i) for family in FAMILIES for i in (0, 1)]
    print(f"{len(scenes)} scenes a row ({', '.join(FAMILIES)}; seeds {args.seed}, {args.seed + 1}), {args.model}")
    calibration = ruled.card_calibration
    psp, code_fit = PspReconstructor(calibration), CodeFit(calibration)
    single = f"{'single shot (cnn_depth)':^74}"
    print(f"{'':30} {single} | {'multi-shot (fpp_depth)':^29}")
    print(
        f"{'':30} {'misfit rad':>13} {'refused':>8}   {'with the rule':>14}   {'without':>22}"
        f" | {'misfit rad':>11} {'warned':>6} {'error':>6}"
    )
    print(
        f"{'':30} {'':>13} {'':>8}   {'cover':>6} {'>1mm':>7}   {'cover':>6} {'>1mm':>7} {'>0.25mm':>7}"
        f" | {'':>11} {'':>6} {'mm':>6}"
    )
    for name, knock in KNOCKS.items():
        rig = replace(base, **knock)
        ruled_totals, unruled_totals, misfits, refused = ErrorTotals(), [ErrorTotals(), ErrorTotals()], [], 0
        code_misfits, errors = [], []
        for family, seed in scenes:
            capture = render(rig, make_scene(rig, family, seed), patterns, np.random.default_rng(seed))
            truth = np.where(capture.valid, capture.depth_mm, np.nan)
            image = capture.images[patterns.single_shot_index]
            frame = ruled.frame(image)
            out = ruled.outputs(frame)  # one network run; each model decodes it with its own decoder
            ruled_totals.add(ruled.decode(frame, out)[0], truth, 1.0)
            misfits.append(ruled.decoder.misfit)
            refused += "frames from a rig that no longer fits its calibration" in ruled.warnings()
            depth = unruled.decode(frame, out)[0]
            for total, bound in zip(unruled_totals, (1.0, 0.25)):
                total.add(depth, truth, bound)
            multi = psp(capture.images)
            code_misfits.append(code_fit(image, multi.depth_mm, multi.phase))
            errors.append(np.abs(multi.depth_mm - truth)[np.isfinite(multi.depth_mm) & capture.valid])
        without, warned = unruled_totals[0], sum(m > MAX_CODE_MISFIT_RAD for m in code_misfits)
        print(
            f"{name:30} {min(misfits):5.3f}-{max(misfits):5.3f} {refused:5d}/{len(scenes)}   "
            f"{ruled_totals.coverage:6.1%} {ruled_totals.share_over:7.2%}   "
            f"{without.coverage:6.1%} {without.share_over:7.2%} {unruled_totals[1].share_over:7.1%}"
            f" | {min(code_misfits):5.3f}-{max(code_misfits):5.3f} "
            f"{warned:2d}/{len(scenes)} {np.median(np.concatenate(errors)):6.3f}"
        )
    # the multi-shot check's false alarms: fresh scenes of every family under the training's random photometry
    misfits = []
    for seed, family in enumerate(FAMILY_NAMES * 3, start=args.seed + 2900):
        rig = random_rig(np.random.default_rng(seed), base)
        capture = render(rig, make_scene(rig, family, seed), patterns, np.random.default_rng(seed))
        multi = psp(capture.images)
        misfits.append(code_fit(capture.images[patterns.single_shot_index], multi.depth_mm, multi.phase))
    measured = np.array([m for m in misfits if np.isfinite(m)])
    print(
        f"\n{len(misfits)} fresh scenes of every family under random photometry, as calibrated: the multi-shot check's "
        f"misfit median {np.median(measured):.3f}, most {measured.max():.3f} rad ({len(misfits) - measured.size} "
        f"with too few pixels to tell); warned {np.count_nonzero(measured > MAX_CODE_MISFIT_RAD)} (more than "
        f"{MAX_CODE_MISFIT_RAD} rad)"
    )
    files = split_files(args.data, "val")
    if not files:
        print(f"\nno validation frames in {Path(args.data) / 'val'}: make the set (python -m training.dataset)")
        return
    misfits = []
    for path in files:
        ruled(load_sample(path)[0])
        misfits.append(ruled.decoder.misfit)
    print(
        f"\n{len(files)} validation frames of {args.data}, as calibrated: misfit median {np.median(misfits):.3f}, "
        f"most {max(misfits):.3f} rad; refused {np.count_nonzero(np.array(misfits) > ruled.max_misfit_rad)} "
        f"(the rule: more than {ruled.max_misfit_rad} rad)"
    )


if __name__ == "__main__":
    main()
