"""Stripes laid near the carrier, the texture one image reads worst: a plane at the stand-off (albedo 0.6
striped at contrast 0.66, the default rig) under stripes of several periods and angles from the
fringes' direction, each single-shot model's share of the lit pixels given a depth and of its output off
by more than 1 mm, then those shares over the angles within 20 degrees and over 45-90 degrees. The
carrier is 2.2 mm (9.2 px) apart on that plane. Then other textures with some of their light near the
carrier, on scenes (the sculpture and three training families, seeds 6071-6072, every surface of albedo
0.8 times the texture, measured as single_shot_conditions.py measures its own): barcodes (bars 2-11 px
wide at random) along, at 30 degrees to and across the fringes, checkers 8 and 12 px apart, and wood
grain; the same shares.

    source scripts/env.bash && python scripts/carrier_stripes.py MODEL.onnx [MODEL2.onnx ...]

One image reads such stripes as a shift of the carrier's phase except through what they do to the code
gratings (the carrier's sidebands at the codes' frequencies), so a network knows them only from training
scenes that hold them (training.dataset's composite_stripes; docs/single-shot-trials.md).
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np
from single_shot_conditions import measure  # the conditions' textured scenes, rendered once for all models

from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.model import DepthModel
from fpp_nodes.core.scenes import plane_scene
from fpp_nodes.core.simulation import Rig, Scene, render

PERIODS_MM = (1.6, 1.8, 2.0, 2.2, 2.4, 2.7, 3.0)
ANGLES_DEG = (0, 5, 10, 20, 45, 90)


def barcode(angle_deg: float):
    """Bars 2-11 camera pixels wide at random (0.5-2.7 mm at the stand-off), contrast 0.85, angle_deg from
    the fringes' direction."""

    def texture(rng, patterns, xp, yp):
        y, x = np.indices(xp.shape)
        u = x * np.cos(np.radians(angle_deg)) + y * np.sin(np.radians(angle_deg))
        edges = np.cumsum(rng.integers(2, 12, size=4000))
        return 1 - 0.85 * (np.searchsorted(edges, (u - u.min()).astype(int)) % 2)

    return texture


def checkers(period_px: int):
    def texture(rng, patterns, xp, yp):
        y, x = np.indices(xp.shape)
        return 1 - 0.5 * (((x // (period_px / 2)) + (y // (period_px / 2))) % 2 > 0)

    return texture


def wood(rng, patterns, xp, yp):  # rings 6-20 px apart, bent by a smooth random field, any direction
    y, x = np.indices(xp.shape)
    angle = rng.uniform(0, np.pi)
    bend = cv2.GaussianBlur(rng.standard_normal(xp.shape), (0, 0), 20) * 60
    u = x * np.cos(angle) + y * np.sin(angle) + bend
    return 1 - 0.5 * (0.5 + 0.5 * np.sin(2 * np.pi * u / rng.uniform(6, 20))) ** 3


SCENE_TEXTURES = {
    "barcode along the fringes": barcode(0),
    "barcode at 30 deg": barcode(30),
    "barcode across": barcode(90),
    "checkers 8 px": checkers(8),
    "checkers 12 px": checkers(12),
    "wood grain": wood,
}
TEXTURE_SCENES = [(kind, seed) for seed in (6071, 6072) for kind in ("sculpture", "freeform", "blocks", "bust")]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", nargs="+")
    args = parser.parse_args()
    models = [DepthModel(path) for path in args.models]
    rig = Rig()
    patterns = rig.pattern_set()
    plane = plane_scene(rig, rig.standoff_mm)
    x, y = (r * rig.standoff_mm for r in rig.camera().rays())  # mm on the plane
    near, across = ([ErrorTotals() for _ in models] for _ in range(2))
    print(f"given / off by > 1 mm, per model: {' | '.join(args.models)}")
    print(f"{'period':8}" + "".join(f"{f'{a} deg':>{15 * len(models)}}" for a in ANGLES_DEG))
    for period in PERIODS_MM:
        cells = []
        for angle in ANGLES_DEG:
            u = x * np.cos(np.radians(angle)) + y * np.sin(np.radians(angle))  # across the stripes
            albedo = 0.6 * (1.0 - 0.66 * ((u / period) % 1.0 < 0.5))
            capture = render(rig, Scene("stripes", plane.depth_mm, albedo), patterns, np.random.default_rng(31))
            lit = np.where(capture.valid, capture.depth_mm, np.nan)
            for model, within, beyond in zip(models, near, across):
                depth = model(capture.images[patterns.single_shot_index])
                cell = ErrorTotals().add(depth, lit, 1.0)
                cells.append(f"{cell.coverage:6.1%}/{cell.share_over:5.1%}")
                (within if angle <= 20 else beyond).merge(cell)
        print(f"{period:4.1f} mm " + "".join(f"{c:>15}" for c in cells))
    for name, totals in (("within 20 deg", near), ("45-90 deg", across)):
        print(f"{name:14}" + "".join(f"   given {t.coverage:6.1%}, off {t.share_over:6.2%}" for t in totals))
    print(f"\n{len(TEXTURE_SCENES)} scenes, given / off by > 1 mm, per model")
    for name, texture in SCENE_TEXTURES.items():
        totals = [within for within, *_ in measure(models, rig, patterns, TEXTURE_SCENES, texture)]
        print(f"{name:26}" + "".join(f"   given {t.coverage:6.1%}, off {t.share_over:6.2%}" for t in totals))


if __name__ == "__main__":
    main()
