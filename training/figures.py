"""The paper's Figures 2 and 3 for our data and networks, as PNG files.

    python -m training.figures --data data/fpp/single --out docs/pictures \\
        runs/fcn/best.pt runs/aen/best.pt runs/default-unet/best.pt      # checkpoints or ONNX models, any subset

figure2.png  a few test samples, a row each: the input fringe image (the line of Figure 3 marked),
             the ground truth (the simulator's exact depth), and each network's reconstruction,
             rendered as 3-D surfaces with the background removed, as in the paper
figure3.png  height above the background plane along that line: ground truth, the multi-shot label
             (the paper's ground truth), each network, and FTP on the same image

The background plane is fitted to the ground truth (image border first, then every pixel within
0.5 mm of it); "object" pixels are those more than 1 mm in front of it. --also copies other pictures
(e.g. the `fpp` tool's) into the same folder, optionally scaled, as <folder>_<name>.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import yaml

from fpp_nodes import pictures
from fpp_nodes.core.calibration import Calibration
from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.reconstruct import reconstruct_ftp
from fpp_nodes.core.scenes import plane_scene
from fpp_nodes.core.simulation import Rig, Scene, render

from .dataset import load_sample, split_files

PNG = [cv2.IMWRITE_PNG_COMPRESSION, 9]
MARK_BGR = (0, 0, 230)  # the profile's line on the input image
NAMES = {"fcn": "FCN", "aen": "AEN", "unet": "UNet", "phase": "phase-aware"}  # as the paper writes them


def load_models(paths, calibration=None) -> list[tuple[str, object]]:
    """(name, image -> depth mm) of each checkpoint (.pt, run with torch as training.evaluate does)
    or ONNX model (.onnx with its card, run with onnxruntime as cnn_depth does, with the calibration of
    the rig that took the images: None, its card's)."""
    models = []
    for path in map(Path, paths):
        if path.suffix == ".onnx":
            from fpp_nodes.core.model import DepthModel

            model = DepthModel(path, calibration=calibration)
            arch = str(model.card.get("architecture"))
            name = NAMES.get(arch, path.stem) + ("" if path.stem in (arch, "unet") else f" ({path.stem})")
            predict = model
        else:
            from .evaluate import predict_full
            from .train import load_checkpoint, model_from_checkpoint

            net, cfg = model_from_checkpoint(load_checkpoint(path))
            if cfg.arch == "phase":
                raise SystemExit(
                    f"{path}: a phase-aware checkpoint; export it (python -m training.export) and "
                    "pass the .onnx, whose card holds the threshold chosen on validation data"
                )
            name, predict = (
                NAMES.get(cfg.arch, cfg.arch),
                (lambda image, net=net, ds=cfg.downsample: predict_full(net, image, ds)),
            )
        taken = [n for n, _ in models]
        models.append((name if name not in taken else f"{name} ({path.parent.name})", predict))
    return models


def background_plane(truth: np.ndarray, border: int = 16) -> np.ndarray:
    """The plane z = a u + b v + c (mm) of the background behind the objects, per pixel."""
    v, u = np.mgrid[: truth.shape[0], : truth.shape[1]].astype(np.float64)
    ok = np.isfinite(truth)
    fit = ok.copy()
    fit[border:-border, border:-border] = False
    plane = None
    for _ in range(3):
        a = np.stack([u[fit], v[fit], np.ones(int(fit.sum()))], axis=1)
        coef = np.linalg.lstsq(a, truth[fit].astype(np.float64), rcond=None)[0]
        plane = coef[0] * u + coef[1] * v + coef[2]
        fit = ok & (np.abs(truth - plane) < 0.5)
    return plane


def object_box(mask: np.ndarray, margin: int = 12) -> tuple[slice, slice]:
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return slice(None), slice(None)
    return (
        slice(max(rows[0] - margin, 0), rows[-1] + margin + 1),
        slice(max(cols[0] - margin, 0), cols[-1] + margin + 1),
    )


def figures(files, models, calibration: Calibration, panel: int = 260, row: int | None = None):
    """(Figure 2, Figure 3) as BGR images for the samples in files."""
    rows2, profiles = [], []
    for f in files:
        image, label, truth = load_sample(f)
        preds = {name: predict(image) for name, predict in models}
        plane = background_plane(truth)
        obj = np.isfinite(truth) & (plane - truth > 1.0)
        rs, cs = object_box(obj)
        line = pictures.profile_row(np.where(obj, truth, np.nan)) if row is None else row
        lo, hi = pictures.depth_range(truth[obj])

        def view(depth):
            return pictures.cloud_view(
                np.where(obj, depth, np.nan), calibration.camera, size=(panel, panel), lo=lo, hi=hi, step=1
            )

        marked = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        cv2.line(marked, (0, line), (image.shape[1] - 1, line), MARK_BGR, 2)
        crop = marked[rs, cs]
        tiles = [
            cv2.resize(
                crop, (max(1, round(crop.shape[1] * panel / crop.shape[0])), panel), interpolation=cv2.INTER_AREA
            ),
            view(truth),
        ] + [view(p) for p in preds.values()]
        rows2.append(pictures.side_by_side(tiles, [f"input, row {line}", "ground truth"] + list(preds)))
        curves = {
            "ground truth": truth,
            "multi-shot label": label,
            **preds,
            "FTP": reconstruct_ftp(image, calibration).depth_mm,
        }
        heights = {name: (plane - depth)[line, cs] for name, depth in curves.items()}
        top = float(np.nanmax(heights["ground truth"]))
        profiles.append(
            pictures.height_profile(
                line,
                heights,
                ylabel="height above the background (mm)",
                ylim=(-0.15 * top - 1, 1.2 * top + 1),
                x_start=cs.start or 0,
                title=f"{Path(f).stem}, row {line}",
            )
        )
    width = max(r.shape[1] for r in rows2)
    gap = np.full((8, width, 3), 255, np.uint8)
    figure2 = np.vstack(
        sum(([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255), gap] for r in rows2), [])[:-1]
    )
    return figure2, pictures.side_by_side(profiles)


def copy_scaled(item: str, out: Path) -> Path:
    """FILE or FILE:SCALE -> out/<folder>_<name>, resized by SCALE."""
    path, sep, scale = item.rpartition(":")
    if not sep or not scale.replace(".", "", 1).isdigit():
        path, scale = item, "1"
    img = cv2.imread(path, cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"cannot read picture {path}")
    if float(scale) != 1:
        img = cv2.resize(img, None, fx=float(scale), fy=float(scale), interpolation=cv2.INTER_AREA)
    target = out / f"{Path(path).parent.name}_{Path(path).name}"
    cv2.imwrite(str(target), img, PNG)
    return target


def failure_scenes(rig: Rig) -> dict:
    """The shapes a depth-regressing network trained on one family got wrong (issue 10), on the default
    rig's background plane: a 20 mm Gaussian bump, a sphere of radius 40 mm, a plane tilted 15 degrees,
    blocks 30, 60 and 90 mm tall. None is in any data set."""
    x, y = rig.camera().rays()
    X, Y = x * rig.standoff_mm, y * rig.standoff_mm
    plane = plane_scene(rig, rig.standoff_mm).depth_mm
    sphere = np.sqrt(np.clip(40.0**2 - X**2 - Y**2, 0, None))
    blocks = np.select([np.abs(Y) > 30, X < -25, X < 25], [0.0, 30.0, 60.0], 90.0)
    heights = {
        "bump 20 mm": 20.0 * np.exp(-(X**2 + Y**2) / (2 * 18.0**2)),
        "sphere r 40 mm": sphere,
        "blocks 30/60/90 mm": blocks,
    }
    scenes = {name: Scene(name, plane - h, np.full(plane.shape, 0.9)) for name, h in heights.items()}
    scenes["plane tilted 15 deg"] = plane_scene(rig, rig.standoff_mm, tilt_x_deg=15.0)
    return scenes


def failure_figure(models, rig: Rig, seed: int = 5) -> tuple[np.ndarray, list]:
    """A row per failure scene: the fringe image, the exact depth and each model's error (NaN grey), with
    RMSE against the exact depth, the share of output pixels off by more than 1 mm and the coverage of
    lit pixels. Returns the picture and the rows of numbers."""
    patterns, rows, table = rig.pattern_set(), [], []
    for name, scene in failure_scenes(rig).items():
        capture = render(rig, scene, patterns, np.random.default_rng(seed))
        image, truth = capture.images[patterns.single_shot_index], np.where(capture.valid, capture.depth_mm, np.nan)
        tiles, captions = [image, pictures.depth_colours(truth)], [name, "exact depth"]
        for model_name, predict in models:  # each model reads its own single-shot frame (a DepthModel says which)
            depth = predict(capture.images[patterns.input_index(getattr(predict, "reads", "paper"))])
            e = ErrorTotals().add(depth, truth, bound=1.0)
            numbers = (e.rmse, e.share_over, e.coverage)
            table.append((name, model_name, *numbers))
            error = depth - truth
            tiles.append(pictures.error_colours(error, 5.0))
            captions.append(f"{model_name}: {numbers[1]:.0%} >1mm, cover {numbers[2]:.0%}")
        rows.append(pictures.side_by_side(tiles, captions, height=240))
    width = max(r.shape[1] for r in rows)
    picture = np.vstack(
        [cv2.copyMakeBorder(r, 0, 6, 0, width - r.shape[1], cv2.BORDER_CONSTANT, value=(255, 255, 255)) for r in rows]
    )
    return picture, table


def main(argv=None):
    parser = argparse.ArgumentParser(
        prog="python -m training.figures", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("models", nargs="*", help="checkpoints (.pt) or ONNX models (.onnx with card), any subset")
    parser.add_argument("--data", help="a data set folder (training.dataset); without it only --also is done")
    parser.add_argument("--out", required=True)
    parser.add_argument("--split", default="test")
    parser.add_argument("--samples", type=int, default=2, help="rows of Figure 2, spread over the split")
    parser.add_argument("--row", type=int, default=None, help="image row of Figure 3 (default: across the object)")
    parser.add_argument("--panel", type=int, default=260, help="panel height of Figure 2, px")
    parser.add_argument(
        "--also",
        action="append",
        default=[],
        metavar="FILE[:SCALE]",
        help="another picture to copy beside them (repeat for more)",
    )
    parser.add_argument(
        "--failures",
        action="store_true",
        help="failures.png instead: issue 10's failure cases (error maps, +-5 mm) and their numbers",
    )
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.failures:
        picture, table = failure_figure(load_models(args.models), Rig())
        cv2.imwrite(str(out / "failures.png"), picture, PNG)
        print(f"{'scene':22}{'model':>28}{'RMSE mm':>10}{'>1mm':>8}{'cover':>8}")
        for name, model_name, rmse_mm, silent, cover in table:
            print(f"{name:22}{model_name[:27]:>28}{rmse_mm:10.3f}{silent:8.1%}{cover:8.1%}")
        print(
            f"wrote {out / 'failures.png'}; RMSE against the exact depth over the pixels given a depth, "
            ">1mm: share of those off by more than 1 mm, cover: share of lit pixels given a depth"
        )
        return
    written = [copy_scaled(item, out) for item in args.also]
    data = Path(args.data) if args.data else None
    if data is None or not (data / "dataset.yaml").is_file():
        print(f"no data set at {data} (python -m training.dataset makes it): Figures 2 and 3 skipped")
    else:
        calibration = Calibration.from_dict(yaml.safe_load((data / "dataset.yaml").read_text())["calibration"])
        files = split_files(data, args.split)
        if not files:
            raise SystemExit(f"{data} has no {args.split} samples")
        files = [files[i] for i in np.linspace(0, len(files) - 1, min(args.samples, len(files))).round().astype(int)]
        figure2, figure3 = figures(files, load_models(args.models, calibration), calibration, args.panel, args.row)
        for name, img in (("figure2.png", figure2), ("figure3.png", figure3)):
            cv2.imwrite(str(out / name), img, PNG)
            written.append(out / name)
    for p in written:
        print(f"wrote {p} ({p.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
