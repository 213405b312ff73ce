"""Multi-shot speed and accuracy at 640x480 against OpenCV contrib's structured_light PSP.

Run it with `make bench` (it makes .venv-opencv with opencv-contrib-python-headless, which cannot share
a virtual environment with opencv-python-headless). Both methods run in this one process on the same
simulated scenes and the same cv2 build, so their times can be compared as a ratio.

  ours:   16 images (4 steps x frequencies 1, 4, 20, 100) -> temporal unwrapping -> depth + XYZ
  OpenCV: 3 images (3 steps at 100 fringes, what its PSP decodes) of the same scene ->
          computePhaseMap + unwrapPhaseMap (spatial); no depth. For its error we give it an oracle:
          the global sign and 2 pi k offset that best match the true phase, then our calibration's
          depth model.

Errors: RMSE in mm over pixels valid in the method's mask and lit in the ground truth; order errors
are pixels off by more than half a fringe in depth.

First a per-stage table of our path on one scene (each stage's function timed alone, one thread, on
the whole image), so the next bottleneck is visible; then the whole path (its row bands on --threads
threads) beside OpenCV's per scene. To see a CPU without AVX-512 on one that has it:
NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" OPENCV_CPU_DISABLE=AVX512-SKX (the header then
says so) and NUMBA_CPU_NAME=haswell (the compiled passes for AVX2).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fpp_nodes"))
from fpp_nodes.core.fused import trusted_points  # noqa: E402
from fpp_nodes.core.metrics import depth_errors  # noqa: E402
from fpp_nodes.core.phase import blur_variance  # noqa: E402
from fpp_nodes.core.reconstruct import PspReconstructor, multi_frequency_phase  # noqa: E402
from fpp_nodes.core.scenes import make_scene  # noqa: E402
from fpp_nodes.core.simulation import Rig, render  # noqa: E402
from fpp_nodes.core.workflow import fringe_depth_mm, simulated_calibration  # noqa: E402

from machine import describe  # noqa: E402  (scripts/, this script's folder)


def timed(fn, repeat):
    fn()  # warm up
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return result, np.array(times) * 1000


def stage_table(psp: PspReconstructor, images: np.ndarray, repeat: int) -> None:
    """The multi-shot path's stages, each timed alone on the whole image in one thread."""
    patterns, limits = psp.calibration.patterns, psp.limits
    phase, valid, modulation, noise, coarser = multi_frequency_phase(images, patterns, limits)
    height, width = phase.shape
    out = (np.empty_like(phase), np.empty_like(phase), np.empty_like(valid), np.empty((height, width, 3), np.float32))
    limits_mm = np.array([limits.max_depth_noise_mm, limits.max_depth_step_mm, limits.max_depth_bias_mm])
    blur = blur_variance(phase, modulation, coarser, patterns.top_ratio, valid)
    stages = [
        (
            f"{len(patterns.frequencies)} phases, unwrapping, checks (compiled pass 1), phase noise",
            lambda: multi_frequency_phase(images, patterns, limits),
        ),
        (
            "the frame's blur (median over every 8th pixel of every 8th row)",
            lambda: blur_variance(phase, modulation, coarser, patterns.top_ratio, valid),
        ),
        (
            "depth, depth noise, defocus bias, trust rules, XYZ (compiled pass 2)",
            lambda: trusted_points(
                phase, noise, coarser, valid, 0, 0, height, psp._terms, psp._slope, *psp._rays, blur, limits_mm, out
            ),
        ),
    ]
    one_thread = PspReconstructor(psp.calibration, limits, threads=1)
    print(f"{'stage':66} {'ms median':>9}")
    total = 0.0
    for name, fn in stages:
        ms = float(np.median(timed(fn, repeat)[1]))
        total += ms
        print(f"{name:66} {ms:9.2f}")
    print(f"{'sum of the stages':66} {total:9.2f}")
    print(f"{'whole path, 1 thread':66} {np.median(timed(lambda: one_thread(images), repeat)[1]):9.2f}")
    print(f"{f'whole path, {len(psp._bands)} threads':66} {np.median(timed(lambda: psp(images), repeat)[1]):9.2f}\n")


def opencv_psp(rig: Rig, patterns_top: int):
    params = cv2.structured_light_SinusoidalPattern_Params()
    params.width, params.height = rig.projector_width, rig.projector_height
    params.nbrOfPeriods = patterns_top
    params.methodId = cv2.structured_light.PSP
    params.horizontal = False
    params.setMarkers = False
    return cv2.structured_light.SinusoidalPattern_create(params)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=30)
    parser.add_argument("--scenes", default="plane:0,sculpture:1,objects:2")
    parser.add_argument("--threads", type=int, default=2, help="row bands of our path run at once")
    args = parser.parse_args()
    with_opencv = hasattr(cv2, "structured_light")  # in .venv-opencv (make bench); the sensor's own cv2 lacks it

    rig = Rig()
    patterns = rig.pattern_set()
    three_step = rig.pattern_set(frequencies=(1, patterns.frequencies[-1]), steps=3)
    calibration, _ = simulated_calibration(rig, patterns, seed=0)
    ours = PspReconstructor(calibration, threads=args.threads)
    sinus = opencv_psp(rig, patterns.frequencies[-1]) if with_opencv else None
    u, v = rig.camera().ideal_pixels()
    print(describe({"cv2": cv2.getNumThreads(), "ours (row bands)": len(ours._bands)}, libs=("numpy", "cv2")))
    print(
        f"640x480; median of {args.repeat} runs"
        + ("" if with_opencv else "; this cv2 has no structured_light: ours alone (make bench compares with OpenCV)")
        + "\n"
    )
    first = args.scenes.split(",")[0].split(":")
    stage_table(
        ours,
        render(rig, make_scene(rig, first[0], int(first[1])), patterns, np.random.default_rng(int(first[1]))).images,
        args.repeat,
    )
    print(
        f"{'scene':14} {'method':34} {'images':>6} {'ms median':>9} {'ms p90':>7} "
        f"{'RMSE mm':>8} {'cover':>6} {'orders':>7}"
    )
    for item in args.scenes.split(","):
        kind, seed = item.split(":")
        scene = make_scene(rig, kind, int(seed))
        capture = render(rig, scene, patterns, np.random.default_rng(int(seed)))
        capture3 = render(rig, scene, three_step, np.random.default_rng(int(seed) + 1))
        rec, t_ours = timed(lambda: ours(capture.images), args.repeat)
        fringe = fringe_depth_mm(calibration, calibration.model.phase_at_depth(capture.depth_mm, u, v))
        e_ours = depth_errors(rec.depth_mm, capture.depth_mm, capture.valid, fringe)
        name = f"{kind}-{seed}"
        print(
            f"{name:14} {'ours: phase, unwrap, depth + XYZ':34} {16:6d} {np.median(t_ours):9.1f} "
            f"{np.percentile(t_ours, 90):7.1f} {e_ours.rmse_mm:8.4f} {e_ours.coverage:6.1%} {e_ours.order_errors:7d}"
        )
        if not with_opencv:
            continue
        images3 = [np.ascontiguousarray(img) for img in capture3.images[three_step.top_frequency_frames]]
        (wrapped, shadow), t_phase = timed(lambda: sinus.computePhaseMap(images3), args.repeat)
        unwrapped, t_unwrap = timed(
            lambda: sinus.unwrapPhaseMap(wrapped, (rig.width, rig.height), shadowMask=shadow), args.repeat
        )
        true_phase = calibration.model.phase_at_depth(capture.depth_mm, u, v)
        best = None
        for sign in (1.0, -1.0):  # oracle alignment: the sign and 2 pi k that fit the truth best
            aligned = sign * unwrapped.astype(np.float64)
            lit = capture.valid & (shadow > 0)
            aligned += 2 * np.pi * np.rint(np.median((true_phase - aligned)[lit]) / (2 * np.pi))
            depth = calibration.model.depth(aligned, u, v)
            depth[shadow == 0] = np.nan
            e = depth_errors(depth, capture.depth_mm, capture.valid, fringe)
            best = e if best is None or e.rmse_mm < best.rmse_mm else best
        t_cv = t_phase + t_unwrap
        print(
            f"{'':14} {'OpenCV computePhaseMap':34} {3:6d} {np.median(t_phase):9.1f} {np.percentile(t_phase, 90):7.1f}"
        )
        print(
            f"{'':14} {'OpenCV unwrapPhaseMap':34} {'':6} {np.median(t_unwrap):9.1f} {np.percentile(t_unwrap, 90):7.1f}"
        )
        print(
            f"{'':14} {'OpenCV total (phase only, no depth)':34} {3:6d} {np.median(t_cv):9.1f} "
            f"{np.percentile(t_cv, 90):7.1f} {best.rmse_mm:8.4f} {best.coverage:6.1%} {best.order_errors:7d}"
        )
        print(f"{'':14} {'time ratio OpenCV / ours':34} {'':6} {np.median(t_cv) / np.median(t_ours):9.2f}\n")


if __name__ == "__main__":
    main()
