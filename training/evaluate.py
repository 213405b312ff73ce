"""The paper's Table 1 for our data: training time and train / validation / test MRE and RMSE (mm)
of each network, beside the classical single-shot baseline (FTP on the same image) and the multi-shot
reference, on the same scenes. Errors are at the camera's full resolution, over pixels valid in the
reference: the multi-shot label (as the paper measures), and, in the last rows, the simulator's exact
depth. MRE = mean(|z - z_ref| / z_ref), RMSE = sqrt(mean((z - z_ref)^2)). Coverage: the share of
the exact depth's pixels a method gives a depth for; fringe-order errors: the share of those off the
exact depth by more than half the depth one fringe period of the highest frequency spans there (about
6 mm at the default rig), the errors a wrong fringe order makes.

    python -m training.evaluate --data data/fpp/single runs/fcn/best.pt runs/aen/best.pt runs/unet/best.pt
    python -m training.evaluate --data data/fpp/families --families runs/phase/phase.onnx runs/surface/surface.onnx
    python -m training.evaluate --data data/fpp/composite --refusals composite.onnx   # where the lit pixels go
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np
import torch

from fpp_nodes.core.calibration import Calibration
from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.model import (
    confident,
    decoded_fringes,
    local_depth,
    network_input,
    refusal_margin,
    trusted_single_shot,
)
from fpp_nodes.core.reconstruct import (
    MAX_MISFIT_RAD,
    CompositeDecoder,
    QualityLimits,
    drop_flying_pixels,
    order_surfaces,
    reconstruct_ftp,
)
from fpp_nodes.core.workflow import fringe_depth_mm, wrong_order_mm

from .dataset import SPLITS, load_sample, read_info, reference_depth, sample_family, split_files
from .models import pad_to_stride
from .train import load_checkpoint, model_from_checkpoint


@torch.no_grad()
def predict_full(model, image: np.ndarray, downsample: int) -> np.ndarray:
    """What cnn_depth does: scale to [0, 1], shrink, pad to the stride, run, crop, grow back, keep
    only the pixels to trust."""
    h, w = image.shape
    x = network_input(image)
    if downsample > 1:
        x = cv2.resize(x, (w // downsample, h // downsample), interpolation=cv2.INTER_AREA)
    padded, (ph, pw) = pad_to_stride(torch.from_numpy(x)[None, None])
    depth = model(padded)[0, 0, :ph, :pw].numpy()
    depth = cv2.resize(depth, (w, h), interpolation=cv2.INTER_LINEAR) if downsample > 1 else depth
    return trusted_single_shot(depth, image)


SILENT_ERROR_MM = 1.0


# An exact depth's plane fits to float32's precision (1e-4 mm at 1.2 m); a recorded set's label, noisy, fits none.
PLANE_TOLERANCE_MM = 0.05
# A backdrop fills much of the view; a floating object's top face, however flat, is none.
MIN_BACKGROUND_SHARE = 0.25


def main_surface(depth: np.ndarray, max_step_mm: float, rays) -> np.ndarray:
    """The pixels of the surfaces continuous with the background in a depth map (NaN: none): of the
    surfaces (order_surfaces: 4-neighbours joined where their depths differ by at most max_step_mm, a
    pixel beside a larger step on none), those with pixels on the background. The background is the
    plane of the largest surface that is a plane with no pixel behind it and at least
    MIN_BACKGROUND_SHARE of the image on it, so the pieces that objects cut it into count together.
    Where no surface is such a plane (a background joined to the objects on it in one surface, no
    background, a recorded label's noise), the largest surface. With half a fringe order for the step
    (Itoh's condition, which CompositeDecoder's surfaces use too): what the single-shot issue calls the
    surfaces continuous with the background. rays: the camera's x/z and y/z per pixel (a plane's
    inverse depth is linear in them)."""
    labels, sizes = order_surfaces(depth, np.isfinite(depth), max_step_mm)
    x, y = (np.broadcast_to(r, depth.shape) for r in rays)
    for label in np.argsort(sizes)[::-1][:8]:  # the background, or a piece of it, is among the largest
        if sizes[label] < 0.01 * depth.size:
            break
        on = labels == label
        terms = np.stack([np.ones(int(sizes[label])), x[on], y[on]], axis=1)
        a, b, c = np.linalg.lstsq(terms, 1.0 / depth[on].astype(np.float64), rcond=None)[0]
        if np.abs(depth[on] - 1.0 / (a + b * x[on] + c * y[on])).max() > PLANE_TOLERANCE_MM:
            continue  # not a plane
        behind = depth - 1.0 / (a + b * x + c * y)  # mm behind the plane
        if np.nanmax(behind) > PLANE_TOLERANCE_MM:
            continue  # something lies behind it: no background
        on_plane = (np.abs(behind) <= PLANE_TOLERANCE_MM) & (labels > 0)
        if np.count_nonzero(on_plane) >= MIN_BACKGROUND_SHARE * depth.size:
            return np.isin(labels, np.unique(labels[on_plane]))
    return (labels == sizes.argmax()) & (labels > 0)


def data_set(data: str) -> tuple[dict, Calibration]:
    """A data set folder's dataset.yaml and the calibration its samples were made with."""
    info = read_info(data)
    return info, Calibration.from_dict(info["calibration"])


def samples(data: str, split: str, limit: int = 0):
    """The split's samples (the first limit; 0: all), each as (family, image, label, reference depth,
    the pixels of its main surface: main_surface)."""
    info, calibration = data_set(data)
    wrong_order, rays = wrong_order_mm(calibration), calibration.camera.rays()
    for f in split_files(data, split)[: limit or None]:
        image, label, truth = load_sample(f)
        reference = reference_depth(label, truth)
        yield (
            sample_family(f, info.get("scene", "?")),
            image,
            label,
            reference,
            main_surface(reference, wrong_order, rays),
        )


# family_table's last row: every sample of the split pooled (what a candidate's bar on validation reads)
ALL_FAMILIES = "all"


def family_table(data: str, model_paths, split: str = "test", limit: int = 0) -> None:
    """Generalisation by scene family, on the split's samples (the families set's test split holds the
    held-out families too): RMSE against the exact depth (a recorded set has none: against its multi-shot
    label), silent errors (the share of output pixels off it by more than SILENT_ERROR_MM), coverage (the
    share of lit pixels given a depth), the coverage of the surfaces continuous with the background in the
    exact depth (main_surface; the largest surface where the scene has no background) and of the other lit
    pixels (isolated objects, tops and gaps that steps cut off: what one image supports there, the issue
    asks to report) and, for a phase-aware model, the mean confidence in the fringe order over the lit
    pixels that show fringes; beside them FTP on the same images where the set is the composite's, and the
    multi-shot label. Wrong orders: the share of output pixels off by more than half a fringe order
    (wrong_order_mm). The last row pools every sample of the split (ALL_FAMILIES)."""
    from .figures import load_models

    info, calibration = data_set(data)
    models = load_models(model_paths, calibration)  # the set's rig
    if calibration.code_models:  # the classical baseline on our pattern
        decoder = CompositeDecoder(calibration)
        models.append(("FTP (composite)", lambda image: reconstruct_ftp(image, calibration, decoder=decoder).depth_mm))
    models.append(("multi-shot (the label)", None))  # what all the sequence's images measure: the reference
    wrong_order = wrong_order_mm(calibration)
    # (family, model) -> ErrorTotals against the exact depth (over 1 mm; over wrong_order; on the main
    # surface; off it); [confidence sum, pixels]
    errors, orders, main, apart, sure = {}, {}, {}, {}, {}
    for family, image, label, reference, on_main in samples(data, split, limit):
        for name, predict in models:
            depth, confidence = (
                (label, None)
                if predict is None
                else predict.infer(image)
                if hasattr(predict, "infer")
                else (predict(image), None)
            )
            key = family, name
            errors.setdefault(key, ErrorTotals()).add(depth, reference, SILENT_ERROR_MM)
            orders.setdefault(key, ErrorTotals()).add(depth, reference, wrong_order)
            main.setdefault(key, ErrorTotals()).add(depth, np.where(on_main, reference, np.nan))
            apart.setdefault(key, ErrorTotals()).add(depth, np.where(on_main, np.nan, reference))
            if confidence is not None:
                known = confidence[np.isfinite(confidence) & np.isfinite(reference)]
                totals = sure.setdefault(key, [0.0, 0])
                totals[0], totals[1] = totals[0] + float(known.sum()), totals[1] + known.size
    for (_, name), totals in list(sure.items()):  # the split as a whole: each family's sums pooled
        pooled = sure.setdefault((ALL_FAMILIES, name), [0.0, 0])
        pooled[0], pooled[1] = pooled[0] + totals[0], pooled[1] + totals[1]
    for table in (errors, orders, main, apart):
        for family, name in list(table):
            table.setdefault((ALL_FAMILIES, name), ErrorTotals()).merge(table[family, name])
    names = [n for n, _ in models]
    held_out = set(info.get("held_out_families", []))
    families = sorted({f for f, _ in errors} - {ALL_FAMILIES}, key=lambda f: (f in held_out, f))  # the held-out last
    families.append(ALL_FAMILIES)
    first = max([14, *(len(f) + 3 for f in families)])  # a recorded set's families are its bags' names
    print(f"{split} split of {data}, by scene family (* held out of training and validation)")
    print(f"{'family':{first}}" + "".join(f"{n[:48]:>51}" for n in names))
    print(f"{'':{first}}" + "".join(f"{'RMSE mm  >1mm  orders   cover   main  apart  conf':>51}" for _ in names))
    for family in families:
        cells = []
        for n in names:
            e, (conf, known) = errors[(family, n)], sure.get((family, n), (0.0, 0))
            rmse = f"{e.rmse:8.3f}" if e.compared else f"{'-':>8}"
            wrong = orders[(family, n)].share_over
            off_main = apart[family, n]
            cells.append(
                f"{rmse} {e.share_over:6.2%} {wrong:6.3%} {e.coverage:7.1%} {main[family, n].coverage:6.1%} "
                + (f"{off_main.coverage:6.1%} " if off_main.reference else f"{'-':>6} ")
                + (f"{conf / known:5.2f}" if known else f"{'-':>5}")
            )
        print(f"{family + (' *' if family in held_out else ''):{first}}" + "".join(f"{c:>51}" for c in cells))
    print(
        "RMSE against the exact depth (a recorded set's: the multi-shot label) over the pixels given a depth; "
        f">1mm: share of those off by more than {SILENT_ERROR_MM:g} mm (silent errors); orders: off by more than "
        f"half a fringe order ({wrong_order:.1f} mm, wrong orders); cover: share of lit pixels given a depth; "
        "main: the same of the surfaces continuous with the background (4-neighbours within "
        f"{wrong_order:.1f} mm of each other in the exact depth; the largest surface where there is no "
        "background, a plane at least a quarter of the image with nothing behind it); apart: the same of the "
        "other lit pixels (isolated objects, the tops and gaps that steps cut off, the pixels beside a step); "
        "conf: a phase-aware model's mean confidence in the fringe order over the lit pixels that show fringes"
    )


# DepthModel.decode's steps for a composite model, in its order, each named by what it refuses
REFUSAL_STEPS = (
    "no fringes",  # the image shows none a network can read (decoded_fringes)
    "no order",  # the pixel's codes name none of the working range, or another than its neighbourhood's
    "depth step",  # beside a step of more than the flying-pixel limit
    "roughness",  # the depth around it scatters by more than the card's limit
    "refused surface",  # confidence 0: too small a surface, striped like the codes, beyond the range
    "low confidence",  # below the card's threshold
    "margin",  # beside a pixel refused where fringes show
    "rig misfit",  # the whole frame: its codes miss the orders named as a rig that moved since calibrating does
)


def refusals(model, image: np.ndarray, out: np.ndarray | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Where a composite model's decoding refuses each pixel of one fringe image: for each of
    REFUSAL_STEPS, the pixels it refuses first (masks, disjoint), and the depth given (NaN elsewhere:
    model.infer's depth). The steps of DepthModel.decode and trusted_single_shot, replayed one by one.
    out: the outputs to decode (default: the network's for image)."""
    out = model.outputs(image) if out is None else out
    fringes = decoded_fringes(image, out, model.min_modulation, model.decoder)
    depth, confidence = model.decoder(out, 0.0, fringes, model.sidebands(image, out))
    steps, left = {}, np.ones(image.shape, bool)

    def refused_first(step, refused):
        nonlocal left
        steps[step], left = refused & left, left & ~refused

    refused_first("no fringes", ~fringes)
    refused_first("no order", np.isnan(depth))
    depth[~drop_flying_pixels(depth, QualityLimits.max_depth_step_mm)] = np.nan
    refused_first("depth step", np.isnan(depth))
    depth, roughness = local_depth(depth)
    depth[~(roughness <= model.max_roughness_mm)] = np.nan
    refused_first("roughness", np.isnan(depth))
    refused_first("refused surface", confidence == 0)
    depth[~confident(confidence, model.min_confidence)] = np.nan
    refused_first("low confidence", np.isnan(depth))
    refusal_margin(depth, fringes, model.margin_px)
    refused_first("margin", np.isnan(depth))
    if model.decoder.misfit_of(out, depth) > MAX_MISFIT_RAD:
        depth[...] = np.nan
    refused_first("rig misfit", np.isnan(depth))
    return steps, depth


def exact_outputs(out: np.ndarray, depth: np.ndarray, calibration: Calibration) -> np.ndarray:
    """A composite network's outputs out with their phases replaced, at their own amplitudes, by those
    the calibration's models give at depth (a sample's exact depth) wherever it is known: what a network
    without phase error would output, so its decoding is depth wherever the rules keep it."""
    u, v = calibration.camera.ideal_pixels()
    known = np.isfinite(depth)
    depth = np.where(known, depth, calibration.reference_depth_mm)
    carrier = calibration.model.phase_at_depth(depth, u, v)
    phases = np.stack([carrier, *calibration.code_phases_at_depth(depth, carrier, u, v)])
    amplitude = np.hypot(out[0::2], out[1::2])
    exact = np.empty_like(out)
    exact[0::2], exact[1::2] = amplitude * np.sin(phases), amplitude * np.cos(phases)
    return np.where(known, exact, out)


def refusal_table(data: str, model_path: str, split: str = "test", limit: int = 0, exact: bool = False) -> None:
    """Where a composite model's decoding refuses the lit pixels, by scene family (refusals): the
    share of the lit pixels each step refuses first, and of those of the surfaces continuous with the
    background (main_surface), beside the share it gives a depth. exact: decode the phases of the exact
    depth instead of the network's (exact_outputs), with the model's rules: what they refuse of a perfect
    network's outputs, the most a better network could give through this decoding."""
    from fpp_nodes.core.model import DepthModel

    info, calibration = data_set(data)
    model = DepthModel(model_path, calibration=calibration)
    if not isinstance(model.decoder, CompositeDecoder):
        raise SystemExit(f"{model_path}: refusals are a composite model's decoding steps")
    counts = {}  # (family, region) -> pixels per step, then given
    for family, image, _, reference, on_main in samples(data, split, limit):
        lit = np.isfinite(reference)
        out = exact_outputs(model.outputs(image), reference, calibration) if exact else None
        steps, depth = refusals(model, image, out)
        for region, pixels in (("lit", lit), ("main", lit & on_main)):
            row = [np.count_nonzero(steps[s] & pixels) for s in REFUSAL_STEPS] + [
                np.count_nonzero(np.isfinite(depth) & pixels)
            ]
            counts[family, region] = counts.get((family, region), 0) + np.array(row)
    held_out = set(info.get("held_out_families", []))
    families = sorted({f for f, _ in counts}, key=lambda f: (f in held_out, f))
    first = max([14, *(len(f) + 8 for f in families)])
    decoded = f"{model_path}'s rules, on the exact depth's phases," if exact else model_path
    print(f"{split} split of {data}: where {decoded} refuses the lit pixels, by scene family (* held out)")
    print(f"{'family':{first}}" + "".join(f"{s:>16}" for s in (*REFUSAL_STEPS, "given")))
    for family in families:
        for region in ("lit", "main"):
            row = counts[family, region]
            name = f"{family}{' *' if family in held_out else ''} {region}"
            print(f"{name:{first}}" + "".join(f"{n / max(row.sum(), 1):16.2%}" for n in row))
    print(
        "each pixel counted at the first step that refuses it, in the decoding's order; lit: every lit pixel; "
        "main: those of the surfaces continuous with the background (as the families table's main column)"
    )


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="python -m training.evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("checkpoints", nargs="*")
    parser.add_argument("--data", required=True)
    parser.add_argument("--limit", type=int, default=0, help="at most N samples per split (0: all)")
    parser.add_argument(
        "--families",
        action="store_true",
        help="the per-family table of the test split instead (checkpoints or .onnx models)",
    )
    parser.add_argument(
        "--refusals",
        action="store_true",
        help="where one composite model's decoding refuses the lit pixels, by family, instead",
    )
    parser.add_argument(
        "--exact",
        action="store_true",
        help="--refusals decoding the exact depth's phases (a recorded set's: its label's) instead of the "
        "network's, with the model's rules: what a network without phase error would get",
    )
    parser.add_argument(
        "--split", choices=SPLITS, default="test", help="--families' and --refusals' split (default: test)"
    )
    args = parser.parse_args(argv)
    if args.exact and not args.refusals:
        parser.error("--exact goes with --refusals")
    if args.refusals and len(args.checkpoints) != 1:
        parser.error("--refusals takes one .onnx model")
    try:  # a missing or broken data set, checkpoint or model: one line, not a traceback
        if args.refusals:
            refusal_table(args.data, args.checkpoints[0], args.split, args.limit, args.exact)
        elif args.families:
            family_table(args.data, args.checkpoints, args.split, args.limit)
        else:
            split_table(args.data, args.checkpoints, args.limit)
    except ValueError as e:
        raise SystemExit(f"evaluate: error: {e}") from None


def split_table(data: str, checkpoints: list, limit: int = 0) -> None:
    """Table 1's form: each checkpoint's, FTP's and the multi-shot label's errors on each split (its
    first limit samples; 0: all)."""
    _, calibration = data_set(data)
    models = []
    for path in checkpoints:
        ckpt = load_checkpoint(path)
        model, cfg = model_from_checkpoint(ckpt)
        models.append((cfg.arch.upper(), model, cfg.downsample, ckpt["train_seconds"], f"{ckpt['epoch']}/{cfg.epochs}"))
    columns = [m[0] for m in models] + ["FTP", "multi-shot"]
    u, v = calibration.camera.ideal_pixels()
    table = {}
    for split in ("train", "val", "test"):
        errs = {c: (ErrorTotals(), ErrorTotals()) for c in columns}  # vs label, vs exact depth
        for f in split_files(data, split)[: limit or None]:
            image, label, truth = load_sample(f)
            preds = {name: predict_full(model, image, ds) for name, model, ds, *_ in models}
            preds["FTP"] = reconstruct_ftp(image, calibration).depth_mm
            preds["multi-shot"] = label
            half_fringe = fringe_depth_mm(calibration, calibration.model.phase_at_depth(truth, u, v)) / 2
            for c in columns:
                errs[c][0].add(preds[c], label)
                errs[c][1].add(preds[c], truth, half_fringe)
        table[split] = errs
    hours = {m[0]: f"{m[3] / 3600:.2f} h" for m in models}
    print(f"{'':28}" + "".join(f"{c:>12}" for c in columns))
    epochs = {m[0]: m[4] for m in models}
    print(f"{'training time (CPU)':28}" + "".join(f"{hours.get(c, '-'):>12}" for c in columns))
    print(f"{'best epoch / epochs':28}" + "".join(f"{epochs.get(c, '-'):>12}" for c in columns))
    for split, label in (("train", "Training"), ("val", "Validation"), ("test", "Test")):
        print(f"{label + ' MRE':28}" + "".join(f"{table[split][c][0].mre:12.2e}" for c in columns))
        print(f"{label + ' RMSE (mm)':28}" + "".join(f"{table[split][c][0].rmse:12.3f}" for c in columns))
    exact = table["test"]
    print(f"{'Test RMSE vs exact (mm)':28}" + "".join(f"{exact[c][1].rmse:12.3f}" for c in columns))
    print(f"{'Test coverage vs exact':28}" + "".join(f"{exact[c][1].coverage:12.2%}" for c in columns))
    print(f"{'Test fringe-order errors':28}" + "".join(f"{exact[c][1].share_over:12.3%}" for c in columns))
    print(
        "errors against the multi-shot label (the paper's ground truth) unless marked exact; "
        "the multi-shot column vs its own label is 0 by definition"
    )


if __name__ == "__main__":
    main()
