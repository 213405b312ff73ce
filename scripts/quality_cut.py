"""Which pixels the multi-shot path keeps, on bright, dark, checkered and striped scenes: the old cut
(fringe modulation B at least 5% of full scale) against the expected depth noise (phase noise from
the residual of the N-step fit, through dz/dphi; QualityLimits.max_depth_noise_mm) at the default
rig; then, at a camera blur of 0.5 (the default rig's), 1 and 1.5 px, the limit on the defocus bias
(the depth a blurred albedo edge moves a pixel by, phase.defocus_phase_bias;
QualityLimits.max_depth_bias_mm).

    python scripts/quality_cut.py            # each sweep on validation scenes, then before/after on others

The sweeps run on validation seeds (where the defaults were chosen); the before/after tables on other
seeds. Errors are against the simulator's exact depth: RMSE, coverage of the lit pixels, and the share
of kept pixels off by more than 1 mm, outside edges and at them (edge: within EDGE_PX of an unlit pixel,
of a depth step of more than 2 mm or of an albedo step of more than 2x, where defocus mixes two
surfaces' fringes into one pixel).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fpp_nodes"))
from fpp_nodes.core.calibration import Calibration, default_calibration_path  # noqa: E402
from fpp_nodes.core.reconstruct import PspReconstructor, QualityLimits, multi_frequency_phase, trusted_depth  # noqa: E402
from fpp_nodes.core.scenes import make_scene  # noqa: E402
from fpp_nodes.core.simulation import Rig, render  # noqa: E402

OLD_MIN_MODULATION = 0.05  # the cut before issue 12, fraction of full scale
EDGE_PX = 3
VALIDATION_SEEDS, REPORT_SEEDS = (2000, 2001), (3000, 3001)
BLURS_PX = (0.5, 1.0, 1.5)


def variants(scene):
    """The scene as it is (bright), dark (albedo x 0.12), checkered and striped (albedo x 0.15 on half
    the surface, in 12-pixel squares and 10-pixel stripes)."""
    v, u = np.indices(scene.albedo.shape)
    checkers = ((u // 12 + v // 12) % 2).astype(bool)
    stripes = (u % 10) < 5
    yield "bright", scene
    yield "dark", replace(scene, albedo=scene.albedo * 0.12)
    yield "checkered", replace(scene, albedo=np.where(checkers, scene.albedo * 0.15, scene.albedo))
    yield "striped", replace(scene, albedo=np.where(stripes, scene.albedo * 0.15, scene.albedo))


def kept_depth(psp: PspReconstructor, images, limits: QualityLimits | None):
    """Depth by the multi-shot path under these limits (mm), or with the old modulation cut (None)."""
    calibration = psp.calibration
    if limits is not None:
        return PspReconstructor(calibration, limits)(images).depth_mm
    phase, valid, modulation, _, _ = multi_frequency_phase(images, calibration.patterns)
    depth = calibration.model.depth(phase, *calibration.camera.ideal_pixels()).astype(np.float32)
    valid &= modulation >= OLD_MIN_MODULATION * 255
    return trusted_depth(depth, valid, QualityLimits.max_depth_step_mm)[0]


def edges(capture, albedo) -> np.ndarray:
    step = np.zeros(capture.valid.shape, bool)
    for axis, cut in ((1, (slice(None), slice(1, None))), (0, (slice(1, None), slice(None)))):
        ratio = np.diff(np.log(np.maximum(albedo, 1e-3)), axis=axis)
        step[cut] |= (np.abs(np.diff(capture.depth_mm, axis=axis)) > 2.0) | (np.abs(ratio) > np.log(2.0))
    near = (~capture.valid | step).astype(np.uint8)
    return cv2.dilate(near, np.ones((2 * EDGE_PX + 1,) * 2, np.uint8)) > 0


def table(psp, rig, seeds, cuts) -> None:
    """Each variant under each cut (label, QualityLimits or None: the old cut), over the sculpture and
    objects scenes of the seeds, each rendered once."""
    print(f"{'scene':12} {'cut':>14} {'cover':>7} {'RMSE mm':>8} {'>1mm':>7} {'>1mm edge':>10}")
    for name in ("bright", "dark", "checkered", "striped"):
        acc = np.zeros((len(cuts), 5))  # lit, kept, squared error, wrong outside edges, wrong at edges
        for seed in seeds:
            for kind in ("sculpture", "objects"):
                scene = dict(variants(make_scene(rig, kind, seed)))[name]
                capture = render(rig, scene, psp.calibration.patterns, np.random.default_rng(seed))
                at_edge = edges(capture, scene.albedo)
                for row, (_, limits) in zip(acc, cuts):
                    depth = kept_depth(psp, capture.images, limits)
                    kept = np.isfinite(depth) & capture.valid
                    error = np.abs(depth - capture.depth_mm)
                    row += (
                        capture.valid.sum(),
                        kept.sum(),
                        float((error[kept] ** 2).sum()),
                        (np.isfinite(depth) & ~at_edge & (error > 1)).sum(),
                        (np.isfinite(depth) & at_edge & (error > 1)).sum(),
                    )
        for (label, _), (lit, kept, sq, wrong, wrong_edge) in zip(cuts, acc):
            print(
                f"{name:12} {label:>14} {kept / lit:7.1%} {np.sqrt(sq / max(kept, 1)):8.4f} "
                f"{wrong / max(kept, 1):7.2%} {wrong_edge / max(kept, 1):10.3%}"
            )


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.parse_args()
    rig = Rig()
    psp = PspReconstructor(Calibration.load(default_calibration_path()))
    unbiased = QualityLimits(max_depth_bias_mm=np.inf)  # the noise cut alone, as it was chosen
    print(f"validation scenes (seeds {VALIDATION_SEEDS}, sculpture and objects): the noise cut swept")
    noise_cuts = [(f"noise <= {t:g}", replace(unbiased, max_depth_noise_mm=t)) for t in (0.1, 0.15, 0.2, 0.25, 0.4)]
    table(psp, rig, VALIDATION_SEEDS, [("B >= 5%", None)] + noise_cuts)
    print(
        f"\nother scenes (seeds {REPORT_SEEDS}): before (B >= 5% of full scale) and after "
        f"(expected noise <= {QualityLimits.max_depth_noise_mm:g} mm, the default)"
    )
    table(psp, rig, REPORT_SEEDS, [("before", None), ("after", unbiased)])
    for blur in BLURS_PX:
        blurred = replace(rig, blur_sigma_px=blur)
        print(f"\nvalidation scenes, camera blur {blur:g} px: the defocus bias limit swept (noise <= 0.2 mm)")
        bias_cuts = [(f"bias <= {t:g}", replace(unbiased, max_depth_bias_mm=t)) for t in (np.inf, 0.25, 0.5, 0.75, 1)]
        table(psp, blurred, VALIDATION_SEEDS, bias_cuts)
    for blur in BLURS_PX:
        print(
            f"\nother scenes, camera blur {blur:g} px: before (no bias limit) and after "
            f"(bias <= {QualityLimits.max_depth_bias_mm:g} mm, the default)"
        )
        table(psp, replace(rig, blur_sigma_px=blur), REPORT_SEEDS, [("before", unbiased), ("after", QualityLimits())])


if __name__ == "__main__":
    main()
