"""Data sets made the way the paper makes them: the input is the single-shot frame (the paper's sets:
the first phase-shifted image of the highest frequency; the composite set: the composite frame that
rides along with every sequence); the label is the multi-shot (PSP) reconstruction of the same scene
from the phase-shift images; the simulator's exact depth is kept beside it, so label errors and network errors can both
be measured. Shadowed and untrusted pixels are invalid in the label and are left out of the loss.

    python -m training.dataset --out data/fpp --set single [--counts 540,60,72] [--workers 2]
    python -m training.dataset --out data/fpp --set composite   # scene families, the composite (see SETS)
    python -m training.dataset --out data/fpp --set composite_retest   # 120 fresh test scenes of the same families
    python -m training.dataset --out data/fpp --set composite_retest2  # and 120 more
    python -m training.dataset --out data/fpp --set composite_hard     # 120 hard validation scenes
    python -m training.dataset --out data/fpp --set composite_reliefs  # low reliefs, steps of 0.5-8 mm
    python -m training.dataset --out data/my_rig --from-bag bags/run1 [--split train]

On disk (a folder per set and split, one file per sample):

    <out>/<set>/dataset.yaml           what made it: set, counts, seeds, rig, pattern set, calibration
    <out>/<set>/<split>/<seed>.npz     input  uint8 (H, W)   the fringe image
                                       label  float32 (H, W) PSP depth in mm, NaN = invalid
                                       truth  float32 (H, W) exact depth in mm, NaN = shadow
     families/surface/composite: phase  float32 (H, W)     multi-shot absolute phase, NaN invalid
                                 fringe float16 (2, H, W)  its numerator and denominator
                                 family str                the scene family (a bag's sample: the bag's name;
                                                           composite_hard: its condition's, HARD_CONDITIONS)
                 composite_hard: condition str             what was beyond training, e.g. 'bust: black print'
                 composite (and bags): code   float16 (2 x codes, H, W)  the code gratings (phase_targets)
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml
from tqdm import tqdm

from fpp_nodes.core.calibration import Calibration, default_calibration_path
from fpp_nodes.core.phase import phase_sums
from fpp_nodes.core.reconstruct import PspReconstructor, full_scale
from fpp_nodes.core.scenes import (
    SCENE_FAMILIES,
    barred_near_the_carrier,
    black_print,
    fine_stripes,
    grating_texture,
    make_scene,
    pink_noise,
    striped_like_the_carrier,
    textured,
)
from fpp_nodes.core.simulation import Rig, beyond_training_rig, random_rig, render

SPLITS = ("train", "val", "test")
# set name -> (scene kind, paper's counts, first seed, single-shot frame); seeds never overlap between
# sets or splits; the paper's sets render the paper's 16 frames (the same images as before the composite)
SETS = {
    "single": ("sculpture", (540, 60, 72), 100_000, "paper"),
    "multi": ("objects", (630, 70, 40), 200_000, "paper"),
    "families": ("families", (1000, 120, 180), 300_000, "paper"),
    "surface": ("families", (600, 48, 96), 400_000, "paper"),
    "composite": ("families", (360, 40, 120), 500_000, "composite"),
    "composite_paper": ("families", (360, 40, 120), 500_000, "paper"),
    "composite_retest": ("families", (0, 0, 120), 600_000, "composite"),
    "composite_retest2": ("families", (0, 0, 120), 700_000, "composite"),
    "composite_hard": ("families", (0, 120, 0), 800_000, "composite"),
    "composite_reliefs": ("reliefs", (120, 40, 40), 1_000_000, "composite"),
    "composite_stripes": ("families", (120, 0, 0), 1_200_000, "composite"),
    "composite_bars": ("families", (180, 0, 0), 1_370_000, "composite"),
}
# composite_paper: the composite set's scenes (the same seeds), the paper's single-shot frame: the two
# patterns compared on the same scenes with the same training budget (README, Table 1).
# composite_retest, composite_retest2: a second and a third draw of the composite set's test scenes (new
# seeds, every family): a candidate network is judged there once the composite test split has been read
# for design choices (the second was, for the quarter-resolution network's; the third for none).
# composite_reliefs: low reliefs (the reliefs family: steps of 0.5-8 mm, under and over half a fringe order),
# which no family of the composite set has; a set of its own, so that the composite set's draws stay as they are.
# composite_stripes: training scenes of the training families with every surface striped near the carrier
# (scenes.striped_like_the_carrier), which the composite set's texture draws hardly ever hold: a lead, not in
# the shipped recipe (make stripes-model adds them to the composite set's training scenes).
# composite_bars: training scenes of the training families with bars near the carrier on patches over about
# half the view (scenes.barred_near_the_carrier), the patches' targets zero: the network is taught to show no
# fringes where one image cannot tell the albedo from the phase (a lead, make bars-model).
# composite_hard: validation scenes of the training families under conditions one image reads worst,
# beyond what training draws (HARD_CONDITIONS): export chooses a network's rules on them beside the
# composite set's (--data twice), so its silent-error budget is spent where one image is hard to read.
# The families set spans the working volume: backgrounds anywhere in 1100-1300 mm. The surface set puts
# the background (the work surface) at the calibration's reference depth at the image centre, any tilt:
# one 100-fringe image cannot tell the fringe order of a surface at an unknown depth (a phase-aware
# network trained on the families set is as unsure as the prior: the conf column of evaluate --families).
# The families set: training and validation see these families; the test split sees every family, so
# the held-out ones (never in training, validation or any design choice) measure generalisation.
TRAIN_FAMILIES = ("bust", "freeform", "blocks", "planes", "floating")
HELD_OUT_FAMILIES = ("spheres", "thin", "objects")
FORMAT_VERSION = 3  # 2: the composite has two code gratings; 3: depth in float32 mm, at any standoff


def load_sample(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(input uint8, label mm float32 NaN-invalid, truth mm float32 NaN-shadow) of one sample."""
    with np.load(path, allow_pickle=False) as z:
        if z["label"].dtype != np.float32:  # format 2 held 1000-1655 mm only, as uint16
            raise ValueError(f"{path} was made by an earlier version of training.dataset: make the set again")
        return z["input"], z["label"], z["truth"]


def reference_depth(label: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """What a sample's output is judged against: its exact depth (a simulated scene), or where it has
    none (a recorded scene: truth all NaN) its multi-shot label."""
    return truth if np.isfinite(truth).any() else label


def sample_family(path, default: str = "?") -> str:
    """The scene family a sample was drawn from (sets without families: default)."""
    with np.load(path, allow_pickle=False) as z:
        return str(z["family"]) if "family" in z else default


def load_phase_targets(path) -> tuple[np.ndarray, np.ndarray, str]:
    """(fringe numerator/denominator float32 (2, H, W), absolute phase float32 NaN-invalid, family)
    of a families-set sample."""
    with np.load(path, allow_pickle=False) as z:
        if "phase" not in z:
            raise ValueError(f"{path} has no phase targets (make a set with them: --set families or surface)")
        return z["fringe"].astype(np.float32), z["phase"], str(z["family"])


def seed_of(set_name: str, split: str, i: int) -> int:
    return SETS[set_name][2] + 10_000 * SPLITS.index(split) + i


_worker = {}


def set_calibration(calibration_path: str, single_shot: str) -> Calibration:
    """The calibration a set is made with: the file's, showing the set's single-shot frame."""
    calibration = Calibration.load(calibration_path)
    return calibration.with_papers_single_shot() if single_shot == "paper" else calibration


def _init(calibration: Calibration):
    _worker.update(rig=Rig(), patterns=calibration.patterns, psp=PspReconstructor(calibration))


def family_of(split: str, i: int) -> str:
    families = TRAIN_FAMILIES if split != "test" else TRAIN_FAMILIES + HELD_OUT_FAMILIES
    return families[i % len(families)]


HARD_CONDITIONS = ("photometry beyond training", "texture beyond training")  # the composite_hard set's families


def hard_texture(rng: np.random.Generator) -> tuple[str, object]:
    """A texture the scene generator never draws, and its name. None is striped like a code: refusing
    those is the stripes rule's job, whose false alarms export measures on plain scenes."""
    which = int(rng.integers(4))
    if which == 0:
        return "black print", black_print
    if which == 1:
        return "1/f noise", pink_noise
    if which == 2:
        period = rng.uniform(3.0, 6.0)
        return f"stripes {period:.1f} px apart", fine_stripes(period)
    contrast = rng.uniform(0.3, 0.7)
    return f"laid like the carrier, contrast {contrast:.2f}", grating_texture(contrast, 0)


def make_sample(
    kind: str,
    seed: int,
    families: bool = False,
    surface_mm: float | None = None,
    hard: bool = False,
    texture: str = "",
) -> dict:
    """Render one scene, reconstruct it with the multi-shot path, keep the single-shot frame.

    For the families set (families=True) the scene is rendered with random photometry (random_rig),
    and the sample also keeps its family and the multi-shot phase: `phase`, the absolute phase of the
    highest frequency (float32, NaN where untrusted), and `fringe`, its numerator and denominator
    (B sin phi, B cos phi over full scale, float16), the phase-aware network's targets. hard: the scene
    under photometry beyond the training ranges or with a texture the generator never draws, drawn
    half and half; its family is which (HARD_CONDITIONS), `condition` says what it is. texture "stripes":
    every surface striped near the carrier (striped_like_the_carrier); "bars": bars near the carrier on
    patches (barred_near_the_carrier), whose pixels get zero fringe and code targets: no fringes to show."""
    rig, patterns, psp = _worker["rig"], _worker["patterns"], _worker["psp"]
    if families:
        rig = random_rig(np.random.default_rng([seed, 1]), rig)
    scene, family, condition, refused = make_scene(rig, kind, seed, surface_mm), kind, None, None
    if texture == "stripes":
        scene = striped_like_the_carrier(rig, patterns, scene, seed)
    elif texture == "bars":
        scene, refused = barred_near_the_carrier(rig, patterns, scene, seed)
    if hard:
        rng = np.random.default_rng([seed, 4])
        if rng.random() < 0.5:
            rig, condition = beyond_training_rig(rng, _worker["rig"])
            family = HARD_CONDITIONS[0]
        else:
            condition, texture = hard_texture(rng)
            scene, family = textured(rig, patterns, scene, texture, seed), HARD_CONDITIONS[1]
    capture = render(rig, scene, patterns, np.random.default_rng(seed))
    rec = psp(capture.images)
    truth = np.where(capture.valid, capture.depth_mm, np.nan)
    sample = {
        "input": capture.images[patterns.single_shot_index],
        "label": rec.depth_mm.astype(np.float32),
        "truth": truth.astype(np.float32),
    }
    if families:
        sample.update(phase_targets(capture.images, rec, psp.calibration), family=family)
    if refused is not None:
        for name in ("fringe", "code"):
            sample[name] = np.where(refused & np.isfinite(sample[name]), np.float16(0), sample[name])
    if condition is not None:
        sample["condition"] = f"{kind}: {condition}"
    return sample


def phase_targets(images: np.ndarray, rec, calibration: Calibration) -> dict:
    """What the phase-aware networks learn, from a sequence and its multi-shot reconstruction:
    `phase`, the absolute phase of the highest frequency (float32, NaN where untrusted); `fringe`, its
    numerator and denominator (B sin phi, B cos phi over full scale, float16, (2, H, W)); with the
    composite also `code`, its code gratings as the multi-shot path sees them: B sin psi_i, B cos psi_i
    for each, psi_i = its row phase at the labelled depth plus the absolute carrier phase / K_i (the
    same B as the carrier's, so every grating's phase weighs the same in the loss)."""
    patterns = calibration.patterns
    top = images[patterns.top_frequency_frames]
    y, x = phase_sums(top)
    scale = 2.0 / (patterns.steps * full_scale(top.dtype))
    targets = {
        "phase": np.where(np.isfinite(rec.depth_mm), rec.phase, np.nan).astype(np.float32),
        "fringe": np.stack([y * scale, x * scale]).astype(np.float16),
    }
    if patterns.single_shot == "composite":
        u, v = calibration.camera.ideal_pixels()
        b = np.hypot(y, x) * scale
        codes = calibration.code_phases_at_depth(rec.depth_mm, rec.phase, u, v)
        targets["code"] = np.stack([b * f(code) for code in codes for f in (np.sin, np.cos)]).astype(np.float16)
    return targets


def _write(job):
    kind, seed, path, families, surface_mm, hard, texture = job
    partial = path.with_suffix(".part")
    with open(partial, "wb") as f:
        np.savez_compressed(f, **make_sample(kind, seed, families, surface_mm, hard, texture))
    partial.replace(path)  # a stopped run leaves no half-written sample behind
    return path


def write_set(out, set_name: str, counts=None, workers: int = 2, calibration_path: str | None = None) -> Path:
    """Make (or finish: existing samples are kept) one data set; returns its folder."""
    kind, paper_counts, _, single_shot = SETS[set_name]
    counts = tuple(counts or paper_counts)
    calibration = set_calibration(calibration_path or default_calibration_path(), single_shot)
    surface_mm = calibration.reference_depth_mm if set_name == "surface" else None
    hard = set_name == "composite_hard"
    texture = {"composite_stripes": "stripes", "composite_bars": "bars"}.get(set_name, "")
    folder = Path(out) / set_name
    jobs = []
    for split, n in zip(SPLITS, counts):
        (folder / split).mkdir(parents=True, exist_ok=True)
        for i in range(n):
            path = folder / split / f"{seed_of(set_name, split, i)}.npz"
            if not path.exists():
                families = kind == "families" or kind in SCENE_FAMILIES  # one family: its samples as the set's
                kind_i = family_of(split, i) if kind == "families" else kind
                jobs.append((kind_i, seed_of(set_name, split, i), path, families, surface_mm, hard, texture))
    rig, patterns = Rig(), calibration.patterns
    (folder / "dataset.yaml").write_text(
        yaml.safe_dump(
            {
                "format": "fpp_dataset",
                "version": FORMAT_VERSION,
                "set": set_name,
                "scene": kind,
                **(
                    {"train_families": list(TRAIN_FAMILIES), "held_out_families": list(HELD_OUT_FAMILIES)}
                    if kind == "families"
                    else {}
                ),
                **({"background_centre_mm": surface_mm} if surface_mm is not None else {}),
                **({"conditions": list(HARD_CONDITIONS)} if hard else {}),
                "counts": dict(zip(SPLITS, counts)),
                "first_seeds": {s: seed_of(set_name, s, 0) for s in SPLITS},
                "input": patterns.names()[patterns.single_shot_index],
                "label": "multi-shot PSP depth",
                "rig": rig.to_dict(),
                "calibration": calibration.to_dict(),
            },
            sort_keys=False,
        )
    )
    with ProcessPoolExecutor(workers, initializer=_init, initargs=(calibration,)) as pool:
        for _ in tqdm(pool.map(_write, jobs), total=len(jobs), desc=f"{set_name} set", disable=None):
            pass
    return folder


def write_bag_set(
    bag, out, split: str = "train", calibration_path: str | None = None, max_time_offset_s: float = 0.005
) -> int:
    """A data set from a recorded bag of full fringe sequences (the path of a user with real hardware:
    record, label with multi-shot, train). Frames are assembled into sequences as capture_sequence
    does; each complete sequence becomes a sample whose label is its multi-shot reconstruction. There
    is no exact depth for a real scene: truth is all NaN. Further bags add to the set (each to its
    split), which stays one rig's: a bag of another calibration is an error. Returns the number of
    samples the bag gave."""
    from fpp_msgs_py import image_to_numpy, stamp_ns  # rosbags' messages have sensor_msgs' fields
    from fpp_nodes.bag import TYPESTORE, read_bag
    from fpp_nodes.core.sequence import SequenceAssembler, ShownPatterns

    recording = read_bag(bag)
    calibration = (
        Calibration.from_yaml(recording.calibration_yaml)
        if calibration_path is None and recording.calibration_yaml
        else Calibration.load(calibration_path or default_calibration_path())
    )
    info_path = Path(out) / "dataset.yaml"
    info = yaml.safe_load(info_path.read_text()) if info_path.exists() else {}
    # the set's images are at full scale (CameraIntrinsics.full_range), so its calibration says no bits
    widened = replace(calibration, camera=replace(calibration.camera, bits=None))
    as_stored = yaml.safe_load(yaml.safe_dump(widened.to_dict()))
    if info and (info.get("set") != "bag" or info.get("calibration") != as_stored):
        raise ValueError(
            f"{out} holds a set of another rig or source than {bag}'s (a data set is one rig's): "
            "give another --out, or the calibration of that set (--calibration)"
        )
    patterns = calibration.patterns
    psp, assembler = PspReconstructor(calibration), SequenceAssembler(patterns.count)
    shown, count = ShownPatterns(patterns, int(max_time_offset_s * 1e9)), 0
    folder = Path(out) / split
    folder.mkdir(parents=True, exist_ok=True)
    for topic, msgtype, _, data in recording.messages:
        if msgtype != "sensor_msgs/msg/Image":
            continue
        msg = TYPESTORE.deserialize_cdr(data, msgtype)
        stamp = stamp_ns(msg.header.stamp)
        image = image_to_numpy(msg)
        if topic.endswith("projector/pattern"):
            shown.add(stamp, image)
            continue
        match = shown.match(stamp)
        if match is None:
            continue
        sequence, _ = assembler.add(match[0], stamp, image.copy(), match[1])
        if sequence is not None:
            rec = psp(sequence.images)
            images = calibration.camera.full_range(sequence.images)  # as the nodes read them (psp does it too)
            composite = phase_targets(images, rec, calibration) if patterns.single_shot == "composite" else {}
            np.savez_compressed(
                folder / f"{sequence.stamps_ns[0]}.npz",
                input=images[patterns.single_shot_index],
                label=rec.depth_mm.astype(np.float32),
                truth=np.full(rec.depth_mm.shape, np.nan, np.float32),
                family=Path(bag).name,  # a recorded set's families are its recordings
                **composite,
            )
            count += 1
    bags = info.get("bags", {})  # split -> the bags its samples came from
    bags[split] = sorted({*bags.get(split, []), str(bag)})
    info_path.write_text(
        yaml.safe_dump(
            {
                "format": "fpp_dataset",
                "version": FORMAT_VERSION,
                "set": "bag",
                "bags": bags,
                "counts": {s: len(split_files(out, s)) for s in SPLITS if (Path(out) / s).is_dir()},
                "input": patterns.names()[patterns.single_shot_index],
                "label": "multi-shot PSP depth",
                "truth": "none (a recorded scene): all NaN",
                "sequences_dropped": info.get("sequences_dropped", 0) + assembler.stats.dropped,
                "calibration": as_stored,
            },
            sort_keys=False,
        )
    )
    return count


def read_info(folder) -> dict:
    """A data set's dataset.yaml: what made it (set, counts, seeds, rig, pattern set, calibration)."""
    path = Path(folder) / "dataset.yaml"
    if not path.is_file():
        raise ValueError(f"{folder} holds no data set (no dataset.yaml): make one with python -m training.dataset")
    return yaml.safe_load(path.read_text())


def sets_calibration(sets: list) -> Calibration:
    """The calibration the sets were made with: one rig's, or an error."""
    first, *others = (read_info(d)["calibration"] for d in sets)
    if any(other != first for other in others):
        raise ValueError(f"{', '.join(map(str, sets))} are not all of one rig (their calibrations differ)")
    return Calibration.from_dict(first)


def split_files(folder, split: str) -> list[Path]:
    return sorted((Path(folder) / split).glob("*.npz"))


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="python -m training.dataset", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", default="data/fpp")
    parser.add_argument("--set", choices=sorted(SETS), action="append", help="default: single and multi (the paper's)")
    parser.add_argument("--counts", help="train,val,test (default: the paper's)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--calibration", help="calibration YAML (default: the simulated rig's, or a bag's own)")
    parser.add_argument("--from-bag", help="make a set from a recorded bag of fringe sequences instead")
    parser.add_argument("--split", default="train", help="the split a bag's samples go to")
    args = parser.parse_args(argv)
    if args.from_bag:
        n = write_bag_set(args.from_bag, args.out, args.split, args.calibration)
        print(f"wrote {n} samples from {args.from_bag} to {Path(args.out) / args.split}")
        return
    counts = None
    if args.counts:
        try:
            counts = [int(c) for c in args.counts.split(",")]
            assert len(counts) == 3 and min(counts) >= 0
        except (ValueError, AssertionError):
            sys.exit(f"dataset: --counts must be three non-negative integers train,val,test, got {args.counts!r}")
    for name in args.set or ("single", "multi"):
        print(f"wrote {write_set(args.out, name, counts, args.workers, args.calibration)}")


if __name__ == "__main__":
    main()
