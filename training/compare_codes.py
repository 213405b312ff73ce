"""Which code for the composite single-shot pattern: one code grating telling 36 orders apart (the
sensor's first composite) against two, one telling 6 orders apart and one 36 (patterns.COMPOSITE_CODES,
shipped), and those two with a third, coarser one (so that no surface outside the working range shows
the codes of an order inside it: scripts/code_aliasing.py), through the same network
(training.models.CompositeNet) and the same training budget.

One code telling 36 orders apart leaves every order decision a margin of 0.07 rad, and the network's
code misses it on textured and dark surfaces: that is where the first composite model's coverage went.
Two codes split the decision, each with a margin of about half a radian, at the price of sharing the
pattern's contrast three ways. What decides is how often each pixel's own codes name the wrong order, measured
here directly.

Every design: scenes of the training families with random photometry (training.dataset's composite
set: its training seeds, and new validation seeds beyond its validation split), the network trained on
exact targets (each grating's phase from the renderer's projector coordinates, B sin, B cos with the
surface's brightness as B), then on the validation scenes: the share of pixels whose own codes name
the wrong order (their errors, together, beyond half the closest two orders' codes: the rig's exact
geometry, every order pair of the working range) and each grating's RMS phase error. With three codes
also the share a decoder judging the finer pair together and the coarsest alone would count (the
coarsest only has to tell the finer pair's turns apart: third_margin: "wrong"), the finer pair's
share alone ("finer"), and the share a decoder asking the coarsest code only across a neighbourhood
(its error's mean phasor over VETO_WINDOW) would call outside the range ("veto"). Pixels: lit,
half the surface's brightness (gain x albedo / 2, the shipped carrier's modulation) at least 2% of full
scale, the same pixels for every design; 16 px from the border. Held-out families are not used: this
chooses a design.

    python -m training.compare_codes [--train 300] [--steps 8000] [--designs NAME ...]
    # about 10 minutes a design on 2 cores with AVX-512, 20 on 2 AVX2 cores
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
import torch

from fpp_nodes.core.patterns import CARRIER_AMPLITUDE, CODE_AMPLITUDE, COMPOSITE_CODES
from fpp_nodes.core.phase import wrap_phase
from fpp_nodes.core.scenes import SURFACE_DEPTH_MM, make_scene
from fpp_nodes.core.simulation import Rig, SceneRenderer, random_rig
from training.dataset import TRAIN_FAMILIES, seed_of
from training.models import CompositeNet
from training.train import photometric

# Each grating: (amplitude, orders it tells apart or None for the carrier, row period in projector pixels)
DESIGNS = {
    "one code (the first)": [(0.5, None, None), (0.5, 36, 17.0)],
    "two codes, rows 8.5/17": [(0.4, None, None), (0.3, 6, 8.5), (0.3, 36, 17.0)],
    "two codes, rows 12/24": [(CARRIER_AMPLITUDE, None, None), *((CODE_AMPLITUDE, k, p) for k, p in COMPOSITE_CODES)],
    # a third, coarser code, so that no surface outside the working range shows the codes of an order
    # inside it (scripts/code_aliasing.py): the codes keep their share of the carrier's amplitude, or
    # the carrier keeps its own
    "+ (216, 48), 0.31/0.23": [(0.31, None, None), *((0.23, k, p) for k, p in (*COMPOSITE_CODES, (216, 48.0)))],
    "+ (180, 96), 0.31/0.23": [(0.31, None, None), *((0.23, k, p) for k, p in (*COMPOSITE_CODES, (180, 96.0)))],
    "+ (180, 96), 0.40/0.20": [(0.40, None, None), *((0.20, k, p) for k, p in (*COMPOSITE_CODES, (180, 96.0)))],
}
CROP, BATCH = 160, 8  # as make composite-model trains
BORDER, FLOOR = 16, 0.02
VETO_WINDOW = 15  # px: the neighbourhood a decoder could ask the coarsest code across


def phases(design, xp, yp, rig: Rig) -> list[np.ndarray]:
    """Each grating's phase at projector coordinates: the carrier's 2 pi f x / W; a code's the row phase
    2 pi y / period plus the carrier's / orders."""
    carrier = 2 * np.pi * rig.pattern_set().frequencies[-1] * xp / rig.projector_width
    return [carrier if orders is None else 2 * np.pi * yp / period + carrier / orders for _, orders, period in design]


def pattern(design, rig: Rig) -> np.ndarray:
    """The projector image: the gratings summed about mid-grey, pre-compensated for the projector's gamma."""
    yp, xp = np.mgrid[: rig.projector_height, : rig.projector_width].astype(np.float64)
    radiance = 0.5 + 0.5 * sum(a * np.cos(p) for (a, _, _), p in zip(design, phases(design, xp, yp, rig)))
    return np.round(255 * np.clip(radiance, 0, 1) ** (1 / rig.projector_gamma)).astype(np.uint8)


def code_samples(design, rig: Rig, depths: np.ndarray, step: int = 16) -> list[np.ndarray]:
    """The carrier's phase, then each code's, at a grid of pixels (every step px) and each depth:
    arrays (depths, rows, columns)."""
    x, y = (a[::step, ::step] for a in rig.camera().rays())
    codes = [g for g in design if g[1] is not None]
    samples = []
    for z in depths:
        xp, yp, _ = rig.to_projector(np.stack([x * z, y * z, np.full(x.shape, z)], axis=-1))
        samples.append(phases([(0, None, None), *codes], xp, yp, rig))
    return [np.array(a) for a in zip(*samples)]


def margin(design, rig: Rig, depths: int = 240) -> float:
    """Half of how close two orders of the working range come in all codes together (rad, the root sum of
    squares of each code's difference; min over a grid of pixels and every pair of depths whole orders
    apart): a pixel whose codes' errors together exceed it may name the wrong order."""
    carrier, *code = code_samples(design, rig, np.linspace(*SURFACE_DEPTH_MM, depths))
    closest = np.inf
    for i in range(0, depths, 2):
        apart = (carrier - carrier[i]) / (2 * np.pi)
        whole = (np.abs(apart - np.rint(apart)) < 0.03) & (np.abs(apart) > 0.5)
        gap = np.sqrt(sum(wrap_phase(c - c[i]) ** 2 for c in code))
        closest = min(closest, float(np.where(whole, gap, np.inf).min()))
    return closest / 2


def third_margin(design, rig: Rig, depths: int = 240) -> float:
    """With three codes, half of how far the coarsest alone sets apart an order inside the working range
    from one outside it (500 mm to 50 m) that the two finer codes cannot tell from it (their codes within
    twice the finer pair's margin): a decoder can judge the coarsest code on its own against this
    (its only task is which turn of the finer pair), the finer pair against theirs."""
    *finer, coarsest = sorted((g for g in design if g[1] is not None), key=lambda g: g[1])
    near, far = SURFACE_DEPTH_MM
    outside_mm = np.concatenate([np.geomspace(500, near - 50, 150), np.geomspace(far + 100, 50000, 450)])
    inside, outside = (code_samples([*finer, coarsest], rig, z) for z in (np.linspace(near, far, depths), outside_mm))
    fine_gap = 2 * margin([(0, None, None), *finer], rig)
    gap = np.inf
    for i in range(0, depths, 2):
        apart = (outside[0] - inside[0][i]) / (2 * np.pi)
        whole = np.abs(apart - np.rint(apart)) < 0.03
        fine = np.sqrt(sum(wrap_phase(o - c[i]) ** 2 for o, c in zip(outside[1:-1], inside[1:-1])))
        third = np.abs(wrap_phase(outside[-1] - inside[-1][i]))
        gap = min(gap, float(np.where(whole & (fine < fine_gap), third, np.inf).min()))
    return gap / 2


def scene(design, image_pattern, seed: int, family: str, base: Rig):
    """(image, each grating's phase, lit, brightness) of one scene with random photometry."""
    rig = random_rig(np.random.default_rng([seed, 1]), base)
    renderer = SceneRenderer(rig, make_scene(rig, family, seed))
    image = renderer.image(image_pattern, 255, np.random.default_rng(seed))
    xp, yp = renderer.projector_xy
    brightness = renderer.reflect[renderer.crop] * np.float32(0.5 / rig.full_scale)
    return image, np.stack(phases(design, xp, yp, rig)).astype(np.float32), renderer.lit[renderer.crop], brightness


def train(images, targets, lit, gratings: int, steps: int) -> CompositeNet:
    """The network on random crops with the training set's photometric augmentation."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    net = CompositeNet(16, gratings)
    optimizer = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, steps)
    h, w = images.shape[1:]
    for _ in range(steps):
        batch = []
        for _ in range(BATCH):
            i, r, c = rng.integers(len(images)), rng.integers(h - CROP + 1), rng.integers(w - CROP + 1)
            crop = (slice(r, r + CROP), slice(c, c + CROP))
            image, gain = photometric(rng, images[i][crop] / np.float32(255))
            phase, brightness = targets[0][i][(slice(None), *crop)], targets[1][i][crop] * gain
            target = np.concatenate([np.stack([brightness * np.sin(p), brightness * np.cos(p)]) for p in phase])
            batch.append((image[None], target, lit[i][crop]))
        x, t, m = (torch.from_numpy(np.stack(b)) for b in zip(*batch))
        loss = 1000.0 * ((net(x) - t) ** 2).sum(dim=1)[m].mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
    return net.eval()


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--train", type=int, default=300, help="training scenes")
    parser.add_argument("--validation", type=int, default=40, help="validation scenes")
    parser.add_argument("--steps", type=int, default=8000, help="training steps (batches of 8 crops)")
    parser.add_argument("--designs", nargs="+", choices=DESIGNS, help="which rows (default: all)")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    base = Rig()
    print(f"{args.train} training scenes, {args.validation} validation scenes, {args.steps} steps of {BATCH} crops")
    print(
        f"{'design':24} {'margin rad':>10} {'own order wrong':>16} {'third alone':>12} {'wrong':>7}"
        f" {'finer':>7} {'veto':>7}  RMS phase error per grating (rad)"
    )
    for name in args.designs or DESIGNS:
        design = DESIGNS[name]
        start, image_pattern = time.time(), pattern(design, base)
        seeds = [(seed_of("composite", "train", i), TRAIN_FAMILIES[i % 5]) for i in range(args.train)]
        seeds += [(seed_of("composite", "val", 1000 + i), TRAIN_FAMILIES[i % 5]) for i in range(args.validation)]
        images, grating_phases, lit, brightness = (
            np.stack(a) for a in zip(*(scene(design, image_pattern, s, f, base) for s, f in seeds))
        )
        n = args.train
        net = train(images[:n], (grating_phases[:n], brightness[:n]), lit[:n], len(design), args.steps)
        half_gap, pixels, wrong, squared = margin(design, base), 0, 0, np.zeros(len(design))
        # with three codes, also: the finer pair judged together and the coarsest alone (third_margin)
        third = len(design) == 4
        if third:
            fine_half, third_half = margin(design[:3], base), third_margin(design, base)
        wrong_alone = fine_only = vetoed = 0
        with torch.no_grad():
            for i in range(n, len(images)):
                out = net(torch.from_numpy(images[i] / np.float32(255))[None, None])[0].numpy()
                misses = wrap_phase(np.arctan2(out[0::2], out[1::2]) - grating_phases[i])
                errors = np.abs(misses)
                keep = lit[i] & (brightness[i] >= FLOOR)
                keep[:BORDER] = keep[-BORDER:] = keep[:, :BORDER] = keep[:, -BORDER:] = False
                pixels += keep.sum()
                wrong += np.count_nonzero(keep & (np.sqrt(np.sum(errors[1:] ** 2, axis=0)) > half_gap))
                if third:
                    fine_unsure = np.sqrt(np.sum(errors[1:3] ** 2, axis=0)) > fine_half
                    wrong_alone += np.count_nonzero(keep & (fine_unsure | (errors[3] > third_half)))
                    fine_only += np.count_nonzero(keep & fine_unsure)
                    # the coarsest code asked across a neighbourhood: its error's mean phasor over the
                    # kept pixels of VETO_WINDOW x VETO_WINDOW around each; beyond third_half it would
                    # call a surface in the range one outside it
                    sums = [
                        cv2.boxFilter(
                            np.where(keep, f(misses[3]), 0).astype(np.float32), -1, (VETO_WINDOW,) * 2, normalize=False
                        )
                        for f in (np.cos, np.sin)
                    ]
                    vetoed += np.count_nonzero(keep & (np.abs(np.arctan2(sums[1], sums[0])) > third_half))
                squared += np.sum(errors[:, keep] ** 2, axis=1)
        names = ["carrier", *(f"code {i + 1}" for i in range(len(design) - 1))]
        rms = "  ".join(f"{g}: {np.sqrt(s / pixels):.3f}" for g, s in zip(names, squared))
        alone = f"{'-':>12} {'-':>7} {'-':>7} {'-':>7}"
        if third:
            alone = f"{third_half:12.3f} {wrong_alone / pixels:7.2%} {fine_only / pixels:7.2%} {vetoed / pixels:7.2%}"
        print(
            f"{name:24} {half_gap:10.3f} {wrong / pixels:16.2%} {alone}  {rms}   ({time.time() - start:.0f} s)",
            flush=True,
        )


if __name__ == "__main__":
    main()
