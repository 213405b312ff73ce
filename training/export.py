"""ONNX export with a parity check, and the model card beside the model.

    python -m training.export runs/unet/best.pt --out fpp_nodes/fpp_nodes/data/models/unet.onnx
    python -m training.export runs/gpu/best.pt --out model.onnx --data data/fpp/composite
    python -m training.export model.onnx --data data/fpp/composite   # its rules chosen again, card rewritten
    python -m training.export runs/x/best.pt --out x.onnx --rules-of fpp_nodes/fpp_nodes/data/models/composite.onnx
    python -m training.export model.onnx --data data/fpp/composite --data data/fpp/composite_hard  # and on hard scenes

The ONNX model has one input, `image` (float32, N x 1 x H x W, the camera image / full scale, at 1/
downsample of the camera's resolution, H and W multiples of 32) and one output, `depth_mm`
(float32, N x 1 x H x W, millimetres along the optical axis); height and width are dynamic. A
composite network's file ends before its last pixel shuffle (its card's output.pixel_shuffle), which
DepthModel does in numpy: onnxruntime's DepthToSpace is slow on CPUs. The export
is checked with onnx.checker, then run with onnxruntime at a size other than the training size and
compared with torch (PARITY_TOLERANCE_MM). The card (<model>.yaml) records the rig, input
normalisation, output units, training data and metrics, and the file's sha256.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import multiprocessing
import os
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import onnx
import onnxruntime as ort
import torch
import yaml

from fpp_nodes.core.calibration import Calibration
from fpp_nodes.core.fused import pixel_shuffle
from fpp_nodes.core.model import (
    MIN_MODULATION,
    TRAINING_LAYOUT,
    PhaseOrderDecoder,
    confident,
    decoded_fringes,
    local_depth,
    network_input,
    network_layout,
    trusted_single_shot,
)
from fpp_nodes.core.patterns import PatternSet
from fpp_nodes.core.reconstruct import CompositeDecoder, QualityLimits, code_sidebands
from fpp_nodes.core.workflow import wrong_order_mm

from .dataset import load_sample, reference_depth, sample_family, sets_calibration, split_files
from .models import CompositeNet, LaidOut
from .train import load_checkpoint, load_initial_weights, model_from_checkpoint, model_from_config, predict

PARITY_TOLERANCE_MM = 1e-3
CARD_FORMAT = "fpp_model_card"


def sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


SILENT_ERROR_BUDGET = 0.005  # the share of output pixels off by > 1 mm the rules may leave, on validation
SILENT_ERROR_LIMIT = 0.01  # ... and in any one validation scene family (the single-shot issue's limit)
WRONG_ORDER_BUDGET = 1e-4  # ... and off by more than half a fringe order (wrong_order_mm): a guessed order
CONFIDENCE_GRID = (0.0, 0.25, 0.5, 0.6, 0.7, 0.75, 0.8, 0.82, 0.84, 0.86, 0.88, 0.9, 0.92, 0.95, 0.98, 0.99, 0.999)
FLOOR_GRID = (0.01, 0.02, 0.03, 0.05)  # the fringe mask's floor: the network's modulation, of full scale
SURFACE_GRID = (0, 500, 2000)  # the composite decoder's smallest surface (pixels) whose vote counts
# the composite's roughness rule (mm; inf: none). It stops at 0.5 on purpose: 0.6-0.8 fit validation's
# budgets but gave 1.5-2.4x the silent errors on darker, noisier, blurrier scenes (docs/single-shot-trials.md,
# the roughness grid's edge)
ROUGHNESS_GRID = (0.15, 0.2, 0.25, 0.3, 0.4, 0.5, np.inf)
MARGIN_GRID = (0, 1, 2, 3)  # pixels around a refused pixel that are refused too (model.refusal_margin)
SIDEBAND_GRID = (0.05, 0.06, 0.07, 0.08, 0.09, 0.1, 0.12, 0.15)  # CompositeDecoder.max_sideband
SIDEBAND_REFUSAL_BUDGET = 0.005  # the share of the validation output the stripes rule may refuse
OUTSIDE_GRID = (0.01, 0.02, 0.03, 0.05, 0.08, 0.12, 0.2)  # CompositeDecoder.max_outside
# every validation surface lies in the working range: what the rule against surfaces outside it refuses there is
# a false alarm, and one chosen at the edge of its false alarms on the training rig false-alarms on rigs unlike it;
# not none, though: a budget of 0 let one stray patch (1e-6 of the output) move a second run of the shipped recipe
# from 0.12 to 0.2, where planes beyond the range came out 14-24% covered, all wrong (docs/single-shot.md)
OUTSIDE_REFUSAL_BUDGET = 1e-5
REFUSAL_BUDGETS = {
    "max_sideband": (SIDEBAND_GRID, SIDEBAND_REFUSAL_BUDGET),
    "max_outside": (OUTSIDE_GRID, OUTSIDE_REFUSAL_BUDGET),
}
OUTPUTS = {"phase": "fringe_order", "composite": "fringe_phases"}  # other architectures: depth_mm


def rule_counts(
    samples,
    decoder,
    floors,
    confidences,
    steps_mm=(QualityLimits.max_depth_step_mm,),
    surfaces_px=(0,),
    roughness_mm=(np.inf,),
    margins_px=(0,),
    wrong_order=np.inf,
    sidebands=(np.inf,),
    outside=(np.inf,),
) -> dict:
    """(floor, surface px, sideband, outside, confidence, step, roughness, margin px) -> {family: [output pixels,
    silent errors (off the exact depth by > 1 mm), exact pixels, wrong orders (off by more than
    wrong_order mm)]} over samples of (image, exact depth, network outputs, family), decoded as
    DepthModel.infer does with that fringe-mask floor, smallest surface, stripes' sidebands and share
    outside the range (a composite decoder's min_surface_px, max_sideband and max_outside),
    order-confidence threshold, edge-rule step,
    roughness limit and refusal margin."""
    counts = {}
    composite = hasattr(decoder, "min_surface_px")
    for image, truth, out, family in samples:
        exact = np.isfinite(truth)
        ratio = code_sidebands(image, out) if composite and np.isfinite(sidebands).any() else None
        for m in floors:
            fringes = decoded_fringes(image, out, m, decoder)
            for px, t, o in ((px, t, o) for px in surfaces_px for t in sidebands for o in outside):
                decode = decoder
                if composite:
                    decode = copy.copy(decoder)
                    decode.min_surface_px, decode.max_sideband, decode.max_outside = px, t, o
                kept, confidence = decode(out, 0.0, fringes, ratio)
                for s in steps_mm:
                    shown = trusted_single_shot(kept.copy(), image, max_depth_step_mm=s, fringes=fringes)
                    mean, roughness = local_depth(shown)
                    for r in roughness_mm:
                        if np.isfinite(r):  # a roughness limit keeps the window's mean
                            smooth, error = roughness <= r, np.abs(mean - truth)
                        else:
                            smooth, error = np.isfinite(shown), np.abs(shown - truth)
                        wrong, guessed = exact & (error > 1.0), exact & (error > wrong_order)
                        for c in confidences:
                            given = smooth & confident(confidence, c)
                            if max(margins_px) > 0:  # how far each pixel is from a refused one (refusal_margin)
                                refused = fringes & ~given
                                far = cv2.distanceTransform((~refused).view(np.uint8), cv2.DIST_C, 3)
                            for k in margins_px:
                                ok = given & (far > k) if k else given
                                n = counts.setdefault((m, px, t, o, c, s, r, k), {}).setdefault(family, np.zeros(4))
                                n += (
                                    ok.sum(),
                                    np.count_nonzero(wrong & ok),
                                    exact.sum(),
                                    np.count_nonzero(guessed & ok),
                                )
    return counts


def rule_rates(by_family: dict) -> dict:
    """One rule's counts by family -> coverage, silent errors and wrong orders over all families, and
    the worst family's silent errors."""
    n = sum(by_family.values())
    return {
        "coverage": n[0] / max(n[2], 1),
        "silent_errors": n[1] / max(n[0], 1),
        "worst_family_silent_errors": max(f[1] / max(f[0], 1) for f in by_family.values()),
        "wrong_orders": n[3] / max(n[0], 1),
    }


def rule_name(floor: float, surface_px: int, roughness_mm: float, margin_px: int = 0) -> str:
    """How a card's validation table names one combination of the rules."""
    return (
        f"floor {floor} surface {surface_px}"
        + (f" roughness {roughness_mm}" if np.isfinite(roughness_mm) else "")
        + (f" margin {margin_px}" if margin_px else "")
    )


@torch.no_grad()
def validation_counts(files, model, decoder, grids: tuple) -> dict:
    """rule_counts (with grids: its arguments after the decoder) of the network's outputs for files."""

    def samples():
        for f in files:
            image, label, truth = load_sample(f)
            out = predict(model, torch.from_numpy(network_input(image))[None, None])[0].numpy()
            yield image, reference_depth(label, truth), out, sample_family(f)

    return rule_counts(samples(), decoder, *grids)


def choose_decoding(model, data: list, calibration: Calibration, limit: int = 200) -> dict:
    """A phase-aware network's rules, decoded with calibration (CompositeDecoder for a CompositeNet,
    else PhaseOrderDecoder): the fringe mask's floor, the smallest surface, the roughness limit and the refusal margin
    (composite decoders) and the order-confidence threshold that give the most coverage while the
    silent errors (output pixels off the exact depth, in a recorded set the multi-shot label, by more
    than 1 mm) stay within SILENT_ERROR_BUDGET over the validation split and within SILENT_ERROR_LIMIT
    in each of its scene families, and the wrong orders within WRONG_ORDER_BUDGET: chosen on
    validation data, never on the test set. Then, with those, a composite decoder's stripes rule: the
    lowest max_sideband of SIDEBAND_GRID that refuses at most SIDEBAND_REFUSAL_BUDGET of that output
    (none is striped like a code, so what it refuses there is its false alarms); then, with that too,
    the lowest max_outside of OUTSIDE_GRID that refuses at most OUTSIDE_REFUSAL_BUDGET of it (every
    surface of the set lies in the working range).

    data: the sets whose validation splits (at most limit samples of each) choose the rules; the first
    set's scenes alone measure the stripes and range rules' false alarms, as the others (hard scenes:
    composite_hard) may hold textures those rules are right to refuse."""
    plain = split_files(data[0], "val")[:limit]
    files = [f for d in data for f in split_files(d, "val")[:limit]]
    composite = isinstance(model, CompositeNet)
    decoder = (CompositeDecoder if composite else PhaseOrderDecoder)(calibration)
    model = LaidOut(model, network_layout(calibration)) if composite else model  # as DepthModel lays frames out
    surfaces, roughness, margins = (SURFACE_GRID, ROUGHNESS_GRID, MARGIN_GRID) if composite else ((0,), (np.inf,), (0,))
    wrong_order, step = wrong_order_mm(calibration), QualityLimits.max_depth_step_mm
    counts = parallel_counts(
        files, model, decoder, (FLOOR_GRID, CONFIDENCE_GRID, (step,), surfaces, roughness, margins, wrong_order)
    )
    rows = {(m, px, c, r, k): rule_rates(n) for (m, px, _, _, c, _, r, k), n in counts.items()}
    good = [
        key
        for key, r in rows.items()
        if r["silent_errors"] <= SILENT_ERROR_BUDGET
        and r["worst_family_silent_errors"] <= SILENT_ERROR_LIMIT
        and r["wrong_orders"] <= WRONG_ORDER_BUDGET
        and r["coverage"] > 0
    ]
    floor, surface, confidence, rough, margin = (
        max(good, key=lambda k: (rows[k]["coverage"], k[2], -k[3]))
        if good
        else (MIN_MODULATION, surfaces[-1], CONFIDENCE_GRID[-1], roughness[0], margins[-1])
    )
    chosen = {"min_confidence": confidence, "min_modulation": floor}
    if composite:
        chosen |= {"min_surface_px": surface, "max_roughness_mm": rough, "margin_px": margin}
        fixed = ((floor,), (confidence,), (step,), (surface,), (rough,), (margin,), wrong_order)
        max_sideband, refused = lowest_within_budget(plain, model, decoder, fixed, "max_sideband", np.inf)
        max_outside, outside_refused = lowest_within_budget(plain, model, decoder, fixed, "max_outside", max_sideband)
        chosen |= {
            "max_sideband": max_sideband,
            "sideband_refusal_budget": SIDEBAND_REFUSAL_BUDGET,
            "sidebands": refused,  # the share of the output each would refuse
            "max_outside": max_outside,
            "outside_refusal_budget": OUTSIDE_REFUSAL_BUDGET,
            "outside": outside_refused,
        }
    return chosen | {
        "chosen_on": " and ".join(f"{d} val" for d in data) + f", {len(files)} samples",
        "silent_error_budget": SILENT_ERROR_BUDGET,
        "silent_error_limit_per_family": SILENT_ERROR_LIMIT,
        "wrong_order_budget": WRONG_ORDER_BUDGET,
        "wrong_order_mm": round(wrong_order, 2),
        "validation": {  # at the chosen floor and smallest surface (all of them: a megabyte of card)
            rule_name(floor, surface, r, k): {
                str(c): {name: round(float(v), 6) for name, v in rows[floor, surface, c, r, k].items()}
                for c in CONFIDENCE_GRID
            }
            for r in roughness
            for k in margins
        },
    }


def lowest_within_budget(files, model, decoder, fixed: tuple, rule: str, other: float) -> tuple[float, dict]:
    """A refusal rule's threshold, rule max_sideband or max_outside: with the other rules fixed
    (rule_counts' arguments up to wrong_order) and the other refusal rule at other, the lowest of its
    grid that refuses at most its budget (REFUSAL_BUDGETS) of the output, and the share each would refuse
    (the validation scenes show neither stripes like a code nor surfaces outside the range, so what a
    refusal rule refuses there is its false alarms)."""
    thresholds, budget = REFUSAL_BUDGETS[rule]
    which = ("max_sideband", "max_outside").index(rule)  # its place among rule_counts' last two grids
    grids = [(other,), (other,)]
    grids[which] = (*thresholds, np.inf)
    counts = parallel_counts(files, model, decoder, (*fixed, *grids))
    # rule_counts' keys: (floor, surface px, sideband, outside, ...)
    output = {key[2 + which]: sum(n[0] for n in by_family.values()) for key, by_family in counts.items()}
    lowest, refused = lowest_within(output, thresholds, budget)
    return lowest, {str(x): round(r, 6) for x, r in refused.items()}


def lowest_within(output: dict, thresholds, budget: float) -> tuple[float, dict]:
    """output: {threshold: the output pixels a refusal rule leaves at it, np.inf: with the rule off} -> the
    lowest of thresholds that refuses at most budget of the output (np.inf where none does), and
    {threshold: the share it refuses}."""
    refused = {x: float(1 - output[x] / output[np.inf]) if output[np.inf] else 0.0 for x in thresholds}
    return float(min((x for x, r in refused.items() if r <= budget), default=np.inf)), refused


def parallel_counts(files, model, decoder, grids: tuple) -> dict:
    """validation_counts in a process per core (counts add up)."""
    workers = max(min(os.cpu_count() or 1, len(files)), 1)
    if workers == 1:
        return validation_counts(files, model, decoder, grids)
    counts = {}
    spawn = multiprocessing.get_context("spawn")  # not fork: this process has run torch's threads
    with ProcessPoolExecutor(workers, spawn, initializer=torch.set_num_threads, initargs=(1,)) as pool:
        shares = [files[i::workers] for i in range(workers)]
        for part in pool.map(validation_counts, shares, [model] * workers, [decoder] * workers, [grids] * workers):
            for key, by_family in part.items():
                for family, n in by_family.items():
                    counts.setdefault(key, {}).setdefault(family, np.zeros(4))[...] += n
    return counts


class Strided(torch.nn.Module):
    """A CompositeNet without its last pixel shuffle (what its ONNX file holds)."""

    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, image):
        return self.net.strided(image)


def export(
    checkpoint: str,
    out: str,
    parity_size=(192, 256),
    metrics: dict | None = None,
    data: list | None = None,
    rules_of: str | None = None,
) -> dict:
    """data: sets of the same rig, the first's calibration on the card, whose validation splits choose a
    phase-aware model's rules (choose_decoding; default: the set it trained on). rules_of: another model
    file whose card's rules the card takes instead (RULES), unchosen: a candidate judged by the shipped
    network's rules."""
    ckpt = load_checkpoint(checkpoint)
    model, cfg = model_from_checkpoint(ckpt)
    sets = data or [cfg.data]
    data = Path(sets[0])
    phase_aware = cfg.arch in OUTPUTS
    output = OUTPUTS.get(cfg.arch, "depth_mm")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    example = torch.rand(1, 1, 480 // cfg.downsample // 32 * 32, 640 // cfg.downsample // 32 * 32)
    shuffle = getattr(model, "pixel_shuffle", 1)  # a composite network's last pixel shuffle runs in DepthModel
    warnings.filterwarnings("ignore", "You are using the legacy TorchScript-based ONNX export", DeprecationWarning)
    # dynamo=False: the TorchScript exporter gives plain dynamic height/width for this fully convolutional net
    torch.onnx.export(
        Strided(model) if shuffle > 1 else model,
        (example,),
        str(out),
        dynamo=False,
        input_names=["image"],
        output_names=[output],
        dynamic_axes={"image": {0: "batch", 2: "height", 3: "width"}, output: {0: "batch", 2: "height", 3: "width"}},
        opset_version=17,
    )
    onnx.checker.check_model(onnx.load(str(out)))
    probe = torch.rand(1, 1, *parity_size)
    with torch.no_grad():
        expected = model(probe).numpy()
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    got = session.run([output], {"image": probe.numpy()})[0]
    got = pixel_shuffle(got[0], shuffle)[None] if shuffle > 1 else got
    np.testing.assert_allclose(got, expected, atol=PARITY_TOLERANCE_MM, rtol=0)
    dataset = yaml.safe_load((data / "dataset.yaml").read_text()) if (data / "dataset.yaml").exists() else {}
    last = ckpt["history"][-1] if ckpt["history"] else {}
    calibration = dataset.get("calibration")
    patterns = PatternSet.from_dict(calibration["patterns"]) if calibration else None
    card = {
        "format": CARD_FORMAT,
        "version": 1,
        "model": out.name,
        "sha256": sha256(out),
        "architecture": cfg.arch,
        "width": cfg.width,
        "parameters": sum(p.numel() for p in model.parameters()),
        "input": {
            "name": "image",
            "shape": "N x 1 x H x W, H and W multiples of 32",
            "normalisation": "camera image / full scale (255 for mono8, 65535 for mono16)",
            "content": patterns.names()[patterns.single_shot_index] if patterns else "unknown",
            "downsample": cfg.downsample,
            "camera": dataset.get("calibration", {}).get("camera"),
            **({"layout": TRAINING_LAYOUT} if cfg.arch == "composite" else {}),  # as every rig's frames were shown
        },
        "output": (
            {
                "name": output,
                "channels": "fringe numerator, denominator (full-scale units), r (fringe "
                "orders from the calibration's reference-depth phase), log sigma of r (orders)",
            }
            if cfg.arch == "phase"
            else {
                "name": output,
                "channels": "carrier numerator, denominator, then each code grating's (full-scale units), "
                f"each as {shuffle * shuffle} channels at 1/{shuffle} of the resolution to pixel-shuffle",
                "pixel_shuffle": shuffle,
            }
            if cfg.arch == "composite"
            else {"name": output, "units": "mm along the camera's optical axis"}
        ),
        "rig": dataset.get("rig"),
        "patterns": dataset.get("calibration", {}).get("patterns"),
        "training": {
            "data": cfg.data,
            # what it learned from (checkpoints before they recorded it: the set's counts now)
            "counts": (dataset.get("counts") or {}) | ckpt.get("counts", {}),
            "epochs": ckpt["epoch"],
            "seconds": round(ckpt["train_seconds"], 1),
            "config": ckpt["config"],
        },
        "metrics": metrics
        or {"val_rmse_mm_vs_label": last.get("val_rmse_mm"), "val_mre_vs_label": last.get("val_mre")},
        "parity": {
            "size": list(parity_size),
            "max_abs_diff_mm": float(np.abs(got - expected).max()),
            "tolerance_mm": PARITY_TOLERANCE_MM,
        },
    }
    if phase_aware:
        card["calibration"] = calibration
        card["decoding"] = rules_from(rules_of) if rules_of else choose_decoding(model, sets, sets_calibration(sets))
    out.with_suffix(".yaml").write_text(yaml.safe_dump(card, sort_keys=False))
    return card


# the decoding rules a card holds (choose_decoding's), which DepthModel reads
RULES = (
    "min_confidence",
    "min_modulation",
    "min_surface_px",
    "max_roughness_mm",
    "margin_px",
    "max_sideband",
    "max_outside",
)


def rules_from(model_path: str) -> dict:
    """The rules of another model's card, and where they came from."""
    card_path = Path(model_path).with_suffix(".yaml")
    if not card_path.is_file():
        raise ValueError(f"{model_path} has no card beside it ({card_path.name})")
    decoding = (yaml.safe_load(card_path.read_text()) or {}).get("decoding") or {}
    if "min_confidence" not in decoding:
        raise ValueError(f"{card_path} holds no decoding rules")
    return {k: decoding[k] for k in RULES if k in decoding} | {"chosen_on": f"the rules of {model_path}'s card"}


def choose_again(model_path: str, data: list) -> dict:
    """An exported phase-aware model's rules chosen again (choose_decoding) on the data sets' validation
    splits, decoded with their calibration (sets recorded with the rig it is to run on, or a decoder
    changed since its export), into its card; the network and its sha256 stay as they are."""
    path = Path(model_path)
    card_path = path.with_suffix(".yaml")
    if not path.is_file() or not card_path.is_file():
        raise ValueError(f"{path} is no exported model: it or its card {card_path.name} does not exist")
    card = yaml.safe_load(card_path.read_text())
    if card.get("architecture") not in OUTPUTS:
        raise ValueError(f"{path} is no phase-aware model: it has no rules to choose")
    if sha256(path) != card["sha256"]:
        raise ValueError(f"{path} does not match its card's sha256")
    model, cfg = model_from_config(card["training"]["config"])
    load_initial_weights(model, path, f"{cfg.arch}, width {cfg.width}")
    card["decoding"] = choose_decoding(model.eval(), data, sets_calibration(data))
    card_path.write_text(yaml.safe_dump(card, sort_keys=False))
    return card


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="python -m training.export", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "checkpoint", help="a checkpoint to export, or an exported model (.onnx) whose rules to choose again"
    )
    parser.add_argument("--out", help="the model file to write (a checkpoint's export)")
    parser.add_argument("--rules-of", help="a model whose card's decoding rules the card takes, unchosen")
    parser.add_argument(
        "--data",
        action="append",
        help="a set whose validation split chooses the rules (default: the training set); again for more "
        "(e.g. composite_hard's scenes beyond training): the first's calibration goes on the card",
    )
    args = parser.parse_args(argv)
    again = Path(args.checkpoint).suffix == ".onnx"
    if again and not args.data:
        parser.error("choosing an exported model's rules again needs --data")
    if not again and not args.out:
        parser.error("exporting a checkpoint needs --out")
    try:  # a missing or broken checkpoint, model or data set: one line, not a traceback
        if again:
            decoding = choose_again(args.checkpoint, args.data)["decoding"]
        else:
            card = export(args.checkpoint, args.out, data=args.data, rules_of=args.rules_of)
    except ValueError as e:
        raise SystemExit(f"export: error: {e}") from None
    if again:
        print(f"rewrote the card of {args.checkpoint}: rules chosen on {decoding['chosen_on']}")
        return
    print(
        f"wrote {args.out} ({card['parameters']} parameters, sha256 {card['sha256'][:12]}...) and its card; "
        f"parity at {card['parity']['size']}: {card['parity']['max_abs_diff_mm']:.2e} mm"
    )


if __name__ == "__main__":
    main()
