"""The shipped single-shot model (or --model) on a rig whose photometry leaves the ranges it was trained
on (training's `random_rig`: ambient 0-15% of full scale, gain 0.4-1.0, noise 0.5-3 counts, blur 0.3-1.2
px; the projector's gamma as the patterns assume), on surfaces textured unlike any scene's, and on rigs
of another geometry: does it say NaN, or guess?

Photometry: renders the same scenes (the demo's sculpture and fresh seeds of three training families,
none in any data set) under each condition with the default rig's geometry. Textures: the same scenes,
every surface of albedo 0.8 times a texture the scene generator never draws: black print, 1/f noise,
stripes finer than any it draws, and stripes laid exactly like one of the composite's gratings (the albedo the
projected grating would print on that surface; the worst case for one image, which cannot tell them
from the grating except through what the albedo does to the other gratings). Geometry: each rig is
calibrated from simulated noisy planes 60 mm either side of its stand-off (its working range) and
measures the sculpture and separated objects (fresh seeds) through that calibration, as cnn_depth does
with the rig's calibration; beside it, the same decoded with the model card's calibration (the training
rig's, what cnn_depth used before; '-' for cameras of another size, which it cannot read). Outside
the working range: surfaces nearer or farther than the calibration's working range (1000-1350 mm in the
default rig), where the composite's codes begin to repeat; beside the card's rules, the same without
the rule against them (the decoder's max_outside); with them, planes in the range tilted beyond any
background in training (40-60 degrees against 35). Prints the coverage of the lit pixels, the share
of the output off the exact depth by more than 1 and 4 mm, and the number of frames on which the sensor
warns of the working range.

    python scripts/single_shot_conditions.py [--model M] [--seed S]
    python scripts/single_shot_conditions.py --model CANDIDATE.onnx --against SHIPPED.onnx --seed S [S2 ...]

With --against, both networks read the same renders, side by side, and the script ends with the rule a
candidate network passes before it ships (RULE_BAR): the cells where it breaks it, or "passes".
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.model import RANGE_WARNING, DepthModel, default_model_path
from fpp_nodes.core.scenes import (
    black_print,
    fine_stripes,
    grating_texture,
    make_scene,
    pink_noise,
    plane_scene,
    textured,
)
from fpp_nodes.core.simulation import Rig, Scene, render
from fpp_nodes.core.workflow import simulated_calibration

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
PHOTOMETRY_FAMILIES = ("sculpture", "freeform", "blocks", "bust")


CODE_STRIPED = {
    f"laid like the {name} code, contrast {contrast}": grating_texture(contrast, which)
    for which, name in ((1, "fine"), (2, "coarse"))
    for contrast in (0.4, 0.6)
}
TEXTURES = {
    "none (albedo 0.8)": lambda rng, patterns, xp, yp: np.ones(xp.shape),
    "black print on white (contrast 0.97)": black_print,
    "1/f noise, contrast 0.9": pink_noise,
    "stripes 4 px apart, contrast 0.8": fine_stripes(4.0),
    "laid like the carrier, contrast 0.6": grating_texture(0.6, 0),
    **CODE_STRIPED,
}
GEOMETRIES = {
    "the default rig": {},
    "stand-off 600 mm, the same field of view": dict(standoff_mm=600.0, focal_px=Rig.focal_px / 2),
    "stand-off 1800 mm, the same field of view": dict(standoff_mm=1800.0, focal_px=Rig.focal_px * 1.5),
    "baseline 300 mm": dict(baseline_mm=300.0),
    "baseline 120 mm": dict(baseline_mm=120.0),
    "projector field 300 mm (fringes 1.36x wider)": dict(projector_field_mm=300.0),
    "camera field 124 mm (fringes 1.25x wider)": dict(focal_px=Rig.focal_px * 1.25),
    "projector field 170 mm (light ends in view)": dict(projector_field_mm=170.0),
    "a lens: k1 -0.9 (2.3 px of barrel distortion)": dict(distortion=(-0.9, 0.0, 2e-4, -2e-4, 0.0)),
    # the network reads the image resampled to its trained fringe period (DepthModel.use)
    "camera 1280x960, same field (fringes 2x wider)": dict(width=1280, height=960, focal_px=Rig.focal_px * 2),
    "camera 320x240, same field (fringes 2x finer)": dict(width=320, height=240, focal_px=Rig.focal_px / 2),
    # the composite's code rows scale with its carrier's period (patterns.REFERENCE_CARRIER_PERIOD_PX)
    "projector 1920x1080, the same field": dict(projector_width=1920, projector_height=1080),
    "projector 2560x1600, 440 mm, camera 1280x960": dict(
        width=1280, height=960, projector_width=2560, projector_height=1600, projector_field_mm=440.0
    ),
}
# the families place surfaces by the simulated rig's depths; these two follow any rig's stand-off
GEOMETRY_FAMILIES = ("sculpture", "objects")


def outside_scenes(rig, kind: str, seed: int) -> Scene:
    """A scene with surfaces outside the default rig's working range (1000-1350 mm), by kind: a plane
    650-950 mm away, or 1420-3000 mm, tilted by up to 25 degrees; the demo's sculpture or separated
    objects (their parts that stand off their background, in the range) before a wall at 1500-2500
    mm; a box whose top reaches 880-950 mm from a background in the range. Or, in the range, a plane
    tilted 40-60 degrees towards any direction: steeper than any background in training (35)."""
    rng = np.random.default_rng([seed, 3])
    tilts = rng.uniform(-25, 25, 2)
    if kind == STEEP:
        tilt, direction = np.radians(rng.uniform(40, 60)), rng.uniform(0, 2 * np.pi)
        slopes = np.degrees(np.arctan(np.tan(tilt) * np.array([np.cos(direction), np.sin(direction)])))
        unit = plane_scene(rig, 1.0, *slopes).depth_mm  # depth over the depth at the image centre
        near, far = 1000 / unit.min(), 1350 / unit.max()  # every pixel in the range, as the families' scenes
        return Scene(kind, rng.uniform(near, max(near, far)) * unit, np.full(unit.shape, 0.9))
    if kind == "near planes":
        return plane_scene(rig, rng.uniform(650, 950), *tilts)
    if kind == "far planes":
        return plane_scene(rig, rng.uniform(1420, 3000), *tilts)
    wall = plane_scene(rig, rng.uniform(1500, 2500), *tilts / 2)
    if kind == "objects before a far wall":
        scene = make_scene(rig, ("sculpture", "objects")[seed % 2], seed)
        standing = scene.depth_mm < np.median(scene.depth_mm) - 8  # 12 mm and more off a background within 4
        return Scene(kind, np.where(standing, scene.depth_mm, wall.depth_mm), np.where(standing, scene.albedo, 0.7))
    background = plane_scene(rig, rng.uniform(1150, 1250), *tilts / 5)
    y, x = np.indices(background.depth_mm.shape)
    top, left = rng.integers(40, 240), rng.integers(40, 400)
    box = (y >= top) & (y < top + 200) & (x >= left) & (x < left + 200)
    return Scene(kind, np.where(box, rng.uniform(880, 950), background.depth_mm), np.full(box.shape, 0.8))


STEEP = "planes in the range tilted 40-60 degrees"
OUTSIDE = ("near planes", "far planes", "objects before a far wall", "a box reaching out of the range", STEEP)


def measure(models, rig, patterns, scenes, texture=None, make=make_scene) -> list[list]:
    """Each model's output on scenes (make(rig, kind, seed)) rendered by rig showing patterns, each scene
    rendered once for all: [totals at 1 mm, totals at 4 mm, the frames it warned of the working range on]."""
    totals = [[ErrorTotals(), ErrorTotals(), 0] for _ in models]
    for kind, seed in scenes:
        scene = make(rig, kind, seed)
        if texture is not None:
            scene = textured(rig, patterns, scene, texture, seed)
        capture = render(rig, scene, patterns, np.random.default_rng(seed))
        truth = np.where(capture.valid, capture.depth_mm, np.nan)
        for model, total in zip(models, totals):
            depth = model(capture.images[patterns.single_shot_index])
            total[0].add(depth, truth, 1.0)
            total[1].add(depth, truth, 4.0)
            total[2] += RANGE_WARNING in model.warnings()
    return totals


# The rule for a candidate network (docs/single-shot.md, what a candidate passes before it ships): in no
# row, as the sensor runs (the first column: the rig's calibration, the card's rules), may its share of the
# output off by more than 1 mm, nor its share of the lit pixels given a depth off by more than 1 mm, exceed
# the shipped network's by more than this (the first alone passes a network that gives a depth to far more of
# a plane beyond the range: all of either's output there is wrong), and no code-striped surface may get a
# pixel. The columns beside show what it does without the rig's calibration or a rule, which it never runs
# without.
RULE_BAR = 0.001


def rule_failures(rows: dict, against: dict) -> list[str]:
    """The rows ({row: (coverage, share off by > 1 mm)}) that break the rule against another network's."""
    failures = []
    for row, (coverage, over) in rows.items():
        if row in against:
            peer_coverage, peer_over = against[row]
            for share, mine, peer in (
                ("of the output", over, peer_over),
                ("of the lit pixels given a depth", coverage * over, peer_coverage * peer_over),
            ):
                if mine > peer + RULE_BAR:
                    failures.append(f"{row}: {peer:.2%} -> {mine:.2%} {share} off by more than 1 mm")
        if row in CODE_STRIPED and coverage > 0:
            failures.append(f"{row}: {coverage:.1%} of a code-striped surface given a depth")
    return failures


def cell(within: ErrorTotals, beyond: ErrorTotals, warned: int) -> str:
    return f"{within.coverage:6.1%} {within.share_over:6.2%} {beyond.share_over:7.3%} {warned:4d}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=default_model_path())
    parser.add_argument(
        "--against", help="the shipped network (a candidate's peer): its cells beside, then the rule's verdict"
    )
    parser.add_argument(
        "--seed",
        type=int,
        nargs="+",
        default=[7001],
        help="scenes of seeds seed and seed + 1, outside the range seed + 100 to 103; more seeds pool their scenes",
    )
    args = parser.parse_args(argv)
    paths = [args.model] + ([args.against] if args.against else [])
    scenes = [(family, seed + i) for seed in args.seed for family in PHOTOMETRY_FAMILIES for i in (0, 1)]
    geometry_scenes = [(kind, seed + i) for seed in args.seed for kind in GEOMETRY_FAMILIES for i in (0, 1)]
    base = Rig()
    patterns = base.pattern_set()  # pre-compensated for the default gamma, whatever the projector's is
    models = [DepthModel(path) for path in paths]
    rows = [{} for _ in paths]  # each model's {row: (coverage, share off by > 1 mm)} as the sensor runs

    def row(name: str, totals: list) -> None:
        """Print a row of each model's cells (totals: for each model, for each column) and keep the first."""
        for i, (first, *_) in enumerate(totals):
            rows[i][name] = (first[0].coverage, first[0].share_over)
        text = " | ".join(
            "   ".join(cell(*t) if t else f"{'-':>6} {'-':>6} {'-':>7} {'-':>4}" for t in m) for m in totals
        )
        print(f"{name:46} {text}")

    columns = f"{'cover':>6} {'>1mm':>6} {'>4mm':>7} {'warn':>4}"
    print(f"{len(scenes)} scenes (the sculpture and fresh seeds of freeform, blocks, bust), {' | '.join(paths)}")
    print(f"{'photometry':46} {' | '.join([columns] * len(paths))}")
    for name, changes in CONDITIONS.items():
        row(name, [[t] for t in measure(models, replace(base, **changes), patterns, scenes)])
    print(f"\n{'texture':46} {' | '.join([columns] * len(paths))}")
    for name, texture in TEXTURES.items():
        row(name, [[t] for t in measure(models, base, patterns, scenes, texture)])
    print(f"\n{len(geometry_scenes)} scenes (fresh seeds of the sculpture and of separated objects)")
    pair = f"{'the rig calibration':>26}   {'the card calibration':>26}"
    print(f"{'':46} {' | '.join([pair] * len(paths))}")
    print(f"{'geometry':46} {' | '.join([columns + '   ' + columns] * len(paths))}")
    for name, changes in GEOMETRIES.items():
        rig = replace(base, **changes)
        rig_patterns = replace(patterns, width=rig.projector_width, height=rig.projector_height)
        planes = [rig.standoff_mm + dz for dz in (-60.0, -30.0, 0.0, 30.0, 60.0)]
        calibration, _ = simulated_calibration(rig, rig_patterns, 1, planes, working_range_mm=None)
        decodings = [(DepthModel(path, calibration=calibration), model) for path, model in zip(paths, models)]
        # the card's calibration: its camera's size only
        readable = [d for pair in decodings for d in pair if d.size == (rig.width, rig.height)]
        totals = dict(zip(map(id, readable), measure(readable, rig, rig_patterns, geometry_scenes)))
        row(name, [[totals.get(id(d)) for d in pair] for pair in decodings])
    pair = f"{'the card':>26}   {'without max_outside':>26}"
    print(f"\n{'':46} {' | '.join([pair] * len(paths))}")
    title = f"outside the range, or steeper ({4 * len(args.seed)} scenes each)"
    print(f"{title:46} {' | '.join([columns + '   ' + columns] * len(paths))}")
    withouts = []
    for path in paths:
        without = DepthModel(path)
        without.decoder.max_outside = np.inf
        withouts.append(without)
    for kind in OUTSIDE:
        outside = [(kind, seed + 100 + i) for seed in args.seed for i in range(4)]
        totals = measure(
            [d for pair in zip(models, withouts) for d in pair], base, patterns, outside, make=outside_scenes
        )
        row(kind, [totals[2 * i : 2 * i + 2] for i in range(len(paths))])
    print("cover: share of lit pixels given a depth; >1mm, >4mm: share of those off the exact depth by more;")
    print("warn: the frames on which cnn_depth and fpp warn of the working range (DepthModel.warnings)")
    if args.against:
        failures = rule_failures(rows[0], rows[1])
        print(
            f"\nthe rule against {args.against} (each row's shares of the output and of the lit pixels off by "
            f"more than 1 mm within {RULE_BAR:.1%} of its):"
        )
        print("\n".join(f"  fails: {f}" for f in failures) or "  passes")


if __name__ == "__main__":
    main()
