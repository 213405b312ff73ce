"""`fpp`: fringe projection profilometry without ROS.

fpp patterns    the pattern set as PNG files at the projector's resolution, in projection order
fpp simulate    rig + scene -> fringe images + ground truth
fpp calibrate   captures of planes at known depths, or of a checkerboard at free poses -> calibration file
fpp reconstruct fringe images -> depth (.npy/.tiff), point cloud (.ply), pictures (.png)
fpp evaluate    depth vs ground truth -> RMSE, MRE, coverage (and pictures of the error)
fpp demo        all of the above on the simulated rig, with a table of the results
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import yaml
from tqdm import tqdm

from . import pictures
from .core import io
from .core.board import LENS_MODELS, Board, BoardPose, board_patterns, calibrate_from_board
from .core.calibration import Calibration, CalibrationError, CameraIntrinsics, back_project
from .core.metrics import depth_errors
from .core.patterns import PatternSet, generate_patterns
from .core.reconstruct import CompositeDecoder, PspReconstructor, QualityLimits, Reconstruction, reconstruct_ftp
from .core.scenes import SCENE_KINDS, board_poses, board_scene, make_scene, scene_from_file
from .core.simulation import Rig, render, render_pose
from .core.workflow import (
    CALIBRATION_DEPTHS_MM,
    calibrate_from_planes,
    fringe_depth_mm,
    held_out_scenes,
    score,
    simulated_calibration,
)


def _rig(args) -> Rig:
    return Rig(
        noise_sigma=args.noise,
        blur_sigma_px=args.blur,
        distortion=args.distortion,
        baseline_mm=args.baseline,
        projector_below_mm=args.projector_below,
        projector_roll_deg=args.projector_roll,
    )


def _write_sensor(folder: Path, rig: Rig, patterns: PatternSet) -> None:
    """sensor.yaml: the camera and the pattern set, as fpp calibrate's --sensor reads them."""
    (folder / "sensor.yaml").write_text(
        yaml.safe_dump({"camera": rig.camera().to_dict(), "patterns": patterns.to_dict()}, sort_keys=False)
    )


def _write_capture(folder: Path, capture, rig: Rig, patterns: PatternSet, scene_name: str, seed: int) -> None:
    io.write_stack(folder, capture.images)
    np.save(folder / "depth_gt_mm.npy", capture.depth_mm.astype(np.float32))
    cv2.imwrite(str(folder / "valid_gt.png"), capture.valid.astype(np.uint8) * 255)
    _write_sensor(folder, rig, patterns)
    (folder / "capture.yaml").write_text(
        yaml.safe_dump(
            {"scene": scene_name, "seed": seed, "rig": rig.to_dict(), "images": patterns.names()}, sort_keys=False
        )
    )


def cmd_patterns(args) -> None:
    """What a projector's pattern memory or a display window shows: every frame of a sequence."""
    if args.calibration:
        patterns = Calibration.load(args.calibration).patterns
    else:  # a projector not yet calibrated: its sensor description's set
        patterns = _read_sensor(args.sensor)[1] if args.sensor else Rig().pattern_set()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = []
    for i, image in enumerate(generate_patterns(patterns)):
        names.append(f"pattern_{i:02d}.png")
        if not cv2.imwrite(str(out / names[-1]), image):
            raise OSError(f"cannot write {out / names[-1]}")
    (out / "patterns.yaml").write_text(
        yaml.safe_dump(
            {
                "patterns": patterns.to_dict(),
                "files": [{"file": f, "shows": n} for f, n in zip(names, patterns.names())],
            },
            sort_keys=False,
        )
    )
    print(
        f"wrote {len(names)} patterns ({patterns.width}x{patterns.height}, {patterns.bit_depth}-bit, in projection "
        f"order) and patterns.yaml to {out}"
    )


def cmd_simulate(args) -> None:
    rig = _rig(args)
    patterns = rig.pattern_set(orientation=args.orientation)
    out = Path(args.out)
    if args.board:
        return _simulate_board(rig, patterns, Board.parse(args.board), args.count, args.seed, out)
    for i in tqdm(range(args.count), desc="simulate", disable=None):
        seed = args.seed + i
        if args.scene in SCENE_KINDS:
            scene = make_scene(rig, args.scene, seed, args.depth)
        else:
            scene = scene_from_file(rig, args.scene, args.map_kind)
        capture = render(rig, scene, patterns, np.random.default_rng(seed))
        folder = out if args.count == 1 else out / f"{scene.name}_{seed:04d}"
        _write_capture(folder, capture, rig, patterns, scene.name, seed)
    print(f"wrote {args.count} capture(s) of {patterns.count} images to {out}")


def _simulate_board(rig: Rig, patterns: PatternSet, board: Board, count: int, seed: int, out: Path) -> None:
    """count poses of a calibration board, each in a folder as fpp calibrate --board reads them."""
    rng = np.random.default_rng(seed)
    sets = board_patterns(patterns)
    for i, (rotation, translation) in enumerate(tqdm(board_poses(rig, board, count, rng), desc="poses", disable=None)):
        image, (vertical, horizontal) = render_pose(rig, board_scene(rig, board, rotation, translation), sets, rng)
        folder = out / f"pose_{i:02d}"
        io.write_stack(folder / "vertical", vertical)
        io.write_stack(folder / "horizontal", horizontal)
        cv2.imwrite(str(folder / "board.png"), image)
    _write_sensor(out, rig, patterns)
    print(f"wrote {count} board poses (board.png, vertical/, horizontal/) and sensor.yaml to {out}")


def _read_pose(folder, camera: CameraIntrinsics) -> BoardPose:
    """A board pose's images, at full scale for the sensor description's camera bits."""
    folder = Path(folder)
    if not (folder / "board.png").is_file():
        raise io.InputError(f"pose {folder}: no board.png (the board under full projector light)")
    stacks = [io.read_stack(io.image_paths([folder / name])) for name in ("vertical", "horizontal")]
    images = [io.read_image(folder / "board.png"), *stacks]
    return BoardPose(folder.name, *(camera.full_range(i) for i in images))


def _read_sensor(path) -> tuple[CameraIntrinsics, PatternSet]:
    try:
        data = yaml.safe_load(Path(path).read_text())
        cam = data["camera"]
        return (
            CameraIntrinsics.from_dict(cam),
            PatternSet.from_dict(data["patterns"]),
        )
    except OSError as e:
        raise CalibrationError(f"cannot read sensor description {path}: {e.strerror}") from None
    except (yaml.YAMLError, KeyError, TypeError) as e:
        raise CalibrationError(
            f"sensor description {path} needs 'camera' (width, height, fx, fy, cx, cy) "
            f"and 'patterns' sections ({type(e).__name__}: {e})"
        ) from None


def _working_range(text: str | None) -> tuple[float, float] | None:
    """--working-range NEAR:FAR, checked before anything is read or fitted."""
    if text is None:
        return None
    try:
        near, far = (float(v) for v in text.split(":"))
    except ValueError:
        raise CalibrationError(f"--working-range {text!r} is not NEAR:FAR in mm") from None
    if not 0 < near < far < np.inf:
        raise CalibrationError(f"--working-range {text!r} needs 0 < NEAR < FAR")
    return near, far


def cmd_calibrate(args) -> None:
    args.working_range = _working_range(args.working_range)
    camera, patterns = _read_sensor(args.sensor)
    if args.board:
        return _calibrate_board(args, Board.parse(args.board), patterns, camera)
    stacks, depths = [], []
    for item in tqdm(args.planes, desc="read planes", disable=None):
        folder, sep, depth = item.rpartition(":")
        if not sep:
            raise CalibrationError(f"plane {item!r} must be FOLDER:DEPTH_MM")
        try:
            depths.append(float(depth))
        except ValueError:
            raise CalibrationError(f"plane {item!r}: depth {depth!r} is not a number") from None
        stacks.append(io.read_stack(io.image_paths([folder])))
    calibration, residuals = calibrate_from_planes(
        stacks, depths, camera, patterns, args.reference_depth, working_range_mm=args.working_range
    )
    _save(calibration, args.out)
    for z, r in zip(depths, residuals):
        print(f"plane {z:8.2f} mm: fit RMSE {r * 1000:7.2f} um")
    print(f"wrote {args.out}")


def _save(calibration: Calibration, path) -> None:
    """Write a calibration once its working range is known to fit the composite's code."""
    if calibration.code_models:
        CompositeDecoder(calibration)  # a clear error if the range spans more orders than the code tells
    calibration.save(path)
    print(f"working range {calibration.working_range_mm[0]:g}-{calibration.working_range_mm[1]:g} mm")


def _calibrate_board(args, board: Board, patterns: PatternSet, sensor: CameraIntrinsics) -> None:
    """The camera's intrinsics come from the board; of the sensor description's camera only its bits."""
    poses = [_read_pose(folder, sensor) for folder in tqdm(args.planes, desc="read poses", disable=None)]
    calibration, report = calibrate_from_board(
        poses, board, patterns, args.reference_depth, args.lens, working_range_mm=args.working_range
    )
    calibration.camera = replace(calibration.camera, bits=sensor.bits)
    _save(calibration, args.out)
    print(f"{'pose':24} {'depth mm':>9} {'camera px':>10} {'projector px':>13} {'corners':>8}")
    for p in report.poses:
        print(f"{p.name:24} {p.depth_mm:9.1f} {p.camera_px:10.3f} {p.projector_px:13.3f} {p.corners:8d}")
    for name, c in (("camera", calibration.camera), ("projector", report.projector)):
        lens = ", ".join(f"{k:.4g}" for k in c.distortion)
        print(f"{name}: f {c.fx:.1f} x {c.fy:.1f} px, principal point ({c.cx:.1f}, {c.cy:.1f}), distortion {lens}")
    if report.projector_mirrored:
        print("the projector shows its image mirrored left-right (rear mode): its columns were read mirrored back")
    print(
        f"projector {np.linalg.norm(report.translation_mm):.1f} mm from the camera; the phase-to-depth model is "
        f"within {report.model_fit_mm * 1000:.2f} um RMS of exact triangulation through this geometry"
    )
    print(f"wrote {args.out}")


def _reconstruct(
    images: np.ndarray, calibration: Calibration, method: str, limits: QualityLimits, model_path: str | None = None
):
    if method == "psp":
        return PspReconstructor(calibration, limits)(images)
    index = calibration.patterns.single_shot_index if len(images) > 1 else 0
    if method == "cnn":  # what cnn_depth does, offline
        from .core.model import DepthModel, default_model_path

        model = DepthModel(model_path or default_model_path(), calibration=calibration)  # depth from this rig
        depth, confidence = model.infer(images[index])
        for warning in model.warnings().values():
            print(f"warning: {warning}", file=sys.stderr)
        quality = confidence if confidence is not None else np.isfinite(depth).astype(np.float32)
        return Reconstruction(
            depth,
            back_project(depth, calibration.camera),
            np.isfinite(depth),
            quality,
            np.full(depth.shape, np.nan, np.float32),
        )
    # FTP's codes are noisier than the network's: no threshold of the range rule refuses little enough of its
    # validation output (scripts/ftp_range_rule.py), so it has the warning alone
    decoder = CompositeDecoder(calibration) if calibration.code_models else None
    result = reconstruct_ftp(images[index], calibration, limits, decoder)
    if decoder is not None and (warning := decoder.range_warning()):
        print(f"warning: {warning}", file=sys.stderr)
    return result


def write_pictures(
    out: Path,
    depth_mm: np.ndarray,
    xyz_mm: np.ndarray | None = None,
    truth_mm: np.ndarray | None = None,
    name: str = "",
    method: str = "measured",
    others: dict | None = None,
) -> list[Path]:
    """depth.png (scale bar in mm), cloud.png (oblique view), error.png (with ground truth) and
    profile.png (depth along the row that crosses the objects: truth, this method and others, a dict
    of name -> depth); colours on the truth's range where given. name suffixes all but the profile's
    file name (name "psp" -> depth_psp.png)."""
    suffix = f"_{name}" if name else ""
    reference = truth_mm if truth_mm is not None else depth_mm
    lo, hi = pictures.depth_range(reference)
    row = pictures.profile_row(reference)
    curves = {"ground truth": truth_mm} if truth_mm is not None else {}
    curves.update({method: depth_mm, **(others or {})})
    drawn = {
        f"depth{suffix}.png": pictures.depth_picture(depth_mm, lo, hi, title=f"{method} depth"),
        "profile.png": pictures.height_profile(row, {k: v[row] for k, v in curves.items()}),
    }
    if xyz_mm is not None:
        drawn[f"cloud{suffix}.png"] = pictures.cloud_view(xyz_mm, lo=lo, hi=hi)
    if truth_mm is not None:
        drawn[f"error{suffix}.png"] = pictures.error_picture(depth_mm, truth_mm, title=f"{method} - truth")
    for file, img in drawn.items():
        cv2.imwrite(str(out / file), img)
    return [out / file for file in drawn]


def _truth_beside(images: list, truth: str | None) -> np.ndarray | None:
    """The ground truth in mm (NaN where not lit) given with --truth, or the one fpp simulate wrote
    beside the images (depth_gt_mm.npy, valid_gt.png)."""
    folder = Path(images[0]) if len(images) == 1 and Path(images[0]).is_dir() else None
    if truth is None and (folder is None or not (folder / "depth_gt_mm.npy").is_file()):
        return None
    depth = io.read_depth(truth or folder / "depth_gt_mm.npy")
    mask = (Path(truth).parent if truth else folder) / "valid_gt.png"
    if mask.is_file():
        depth = np.where(io.read_image(mask) > 0, depth, np.nan)
    return depth


def cmd_reconstruct(args) -> None:
    calibration = Calibration.load(args.calibration)
    images = io.read_stack(io.image_paths(args.images))
    if hint := calibration.camera.narrow_hint(images):
        print(f"warning: {hint}", file=sys.stderr)
    limits = QualityLimits(
        max_depth_noise_mm=args.max_depth_noise,
        max_depth_step_mm=args.max_depth_step,
        max_depth_bias_mm=args.max_depth_bias,
        min_modulation=args.min_modulation,
    )
    start = time.perf_counter()
    rec = _reconstruct(images, calibration, args.method, limits, args.model)
    elapsed = time.perf_counter() - start
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    io.write_depth(out, "depth_mm", rec.depth_mm)
    points = io.write_ply(out / "points.ply", rec.xyz_mm / 1000.0, images.mean(axis=0))
    print(
        f"{args.method}: {points} points ({rec.valid.mean():.1%} of pixels) in {elapsed * 1000:.1f} ms, setting up "
        f"included (the path alone: make bench, make bench-cnn) -> {out}"
    )
    if rec.blur_px is not None:  # a focus check: what the bias limit reads
        print(f"fringe blur {rec.blur_px:.2f} px (camera and projector; the default rig's camera: 0.5)")
    truth = _truth_beside(args.images, args.truth)
    if truth is not None and truth.shape != rec.depth_mm.shape:
        raise io.InputError(
            f"ground truth is {truth.shape[1]}x{truth.shape[0]}, the images {images.shape[2]}x{images.shape[1]}"
        )
    written = write_pictures(out, rec.depth_mm, rec.xyz_mm, truth, method=args.method.upper())
    print("pictures: " + ", ".join(str(p) for p in written))


def cmd_evaluate(args) -> None:
    pred = io.read_depth(args.prediction)
    truth = io.read_depth(args.truth)
    if pred.shape != truth.shape:
        raise io.InputError(
            f"prediction is {pred.shape[1]}x{pred.shape[0]}, truth is {truth.shape[1]}x{truth.shape[0]}"
        )
    valid = None
    if args.valid:
        mask = io.read_image(args.valid)
        if mask.shape != truth.shape:
            raise io.InputError(
                f"valid mask {args.valid} is {mask.shape[1]}x{mask.shape[0]}, "
                f"truth is {truth.shape[1]}x{truth.shape[0]}"
            )
        valid = mask > 0
    e = depth_errors(pred, truth, valid)
    print(f"RMSE {e.rmse_mm:.4f} mm   MRE {e.mre:.3e}   coverage {e.coverage:.1%}   pixels {e.pixels}")
    if args.pictures:
        out = Path(args.pictures)
        out.mkdir(parents=True, exist_ok=True)
        written = write_pictures(
            out, pred, None, truth if valid is None else np.where(valid, truth, np.nan), method="prediction"
        )
        print("pictures: " + ", ".join(str(p) for p in written))


def cmd_demo(args) -> None:
    """Calibrate the simulated rig from planes, measure held-out scenes with both methods, report."""
    rig = Rig()
    patterns = rig.pattern_set()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"calibrating from planes at {', '.join(f'{z:g}' for z in CALIBRATION_DEPTHS_MM)} mm ...")
    calibration, residuals = simulated_calibration(rig, patterns, seed=args.seed)
    calibration.save(out / "calibration.yaml")
    print("  fit RMSE per plane (um): " + ", ".join(f"{r * 1000:.1f}" for r in residuals))
    psp, decoder = PspReconstructor(calibration), CompositeDecoder(calibration)
    rows, written = [], []
    for name, scene, seed in tqdm(
        list(held_out_scenes(rig, args.scenes, args.seed + 1000)), desc="scenes", disable=None
    ):
        capture = render(rig, scene, patterns, np.random.default_rng(seed))
        start = time.perf_counter()
        multi = psp(capture.images)
        psp_ms = (time.perf_counter() - start) * 1000
        single = reconstruct_ftp(capture.images[patterns.single_shot_index], calibration, decoder=decoder)
        result = score(multi, capture.depth_mm, capture.valid, calibration, rig.noise_sigma, name)
        ftp = depth_errors(single.depth_mm, capture.depth_mm, capture.valid, fringe_depth_mm(calibration, multi.phase))
        folder = out / name
        folder.mkdir(exist_ok=True)
        truth = np.where(capture.valid, capture.depth_mm, np.nan)
        for method, rec in (("psp", multi), ("ftp", single)):
            io.write_depth(folder, f"depth_{method}_mm", rec.depth_mm)
        written = write_pictures(folder, multi.depth_mm, multi.xyz_mm, truth, "psp", "PSP", {"FTP": single.depth_mm})
        cv2.imwrite(
            str(folder / "depth_ftp.png"),
            pictures.depth_picture(single.depth_mm, *pictures.depth_range(truth), "FTP depth"),
        )
        cv2.imwrite(str(folder / "error_ftp.png"), pictures.error_picture(single.depth_mm, truth, title="FTP - truth"))
        cv2.imwrite(str(folder / "depth_truth.png"), pictures.depth_picture(truth, title="ground truth"))
        written += [folder / n for n in ("depth_ftp.png", "error_ftp.png", "depth_truth.png")]
        io.write_ply(folder / "points_psp.ply", multi.xyz_mm / 1000.0, capture.images[0])
        cv2.imwrite(str(folder / "input.png"), capture.images[-patterns.steps])
        rows.append((name, result, ftp, psp_ms))
    print(
        f"\nheld-out scenes, default rig (noise {rig.noise_sigma} counts, blur {rig.blur_sigma_px} px); "
        "RMSE over pixels valid in both prediction and truth"
    )
    print(
        f"{'scene':18} {'PSP RMSE mm':>11} {'noise-limit':>11} {'ratio':>6} {'orders':>6} {'cover':>6} "
        f"{'FTP RMSE mm':>11} {'FTP orders':>10} {'PSP ms':>7}"
    )
    for name, r, f, ms in rows:
        e = r.errors
        print(
            f"{name:18} {e.rmse_mm:11.4f} {r.noise_limited_rmse_mm:11.4f} {e.rmse_mm / r.noise_limited_rmse_mm:6.2f} "
            f"{e.order_errors:6d} {e.coverage:6.1%} {f.rmse_mm:11.3f} {f.order_errors:10d} {ms:7.1f}"
        )
    print(f"\nwrote depth (.npy/.tiff), point clouds (.ply, metres) and pictures to {out}:")
    print("  " + ", ".join(p.name for p in written) + " in each scene's folder")


def _five_numbers(text: str) -> tuple:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not five comma-separated numbers") from None
    if len(values) != 5:
        raise argparse.ArgumentTypeError(f"{text!r}: give five numbers K1,K2,P1,P2,K3")
    return values


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fpp", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("patterns", help="every pattern of the set as a PNG at the projector's resolution")
    whose = p.add_mutually_exclusive_group()
    whose.add_argument("--calibration", help="whose pattern set (default: the simulated rig's)")
    whose.add_argument(
        "--sensor",
        help="a sensor description (camera and patterns, as fpp calibrate's --sensor): its pattern set, for a "
        "projector not yet calibrated",
    )
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_patterns)

    p = sub.add_parser("simulate", help="render fringe images of a scene with the simulated rig")
    p.add_argument(
        "--scene",
        default="sculpture",
        help=f"{', '.join(SCENE_KINDS)}, or a height map file (.npy, 16-bit PNG, TIFF; mm)",
    )
    p.add_argument("--map-kind", choices=("height", "depth"), default="height", help="what a scene file holds")
    p.add_argument(
        "--depth",
        type=float,
        default=None,
        help="plane depth in mm (scene 'plane'; for a family: its background's depth at the image centre)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--count", type=int, default=1, help="captures with seeds seed, seed+1, ...")
    p.add_argument("--noise", type=float, default=Rig.noise_sigma, help="camera noise, counts")
    p.add_argument("--blur", type=float, default=Rig.blur_sigma_px, help="defocus blur sigma, pixels")
    p.add_argument(
        "--distortion",
        type=_five_numbers,
        default=Rig.distortion,
        metavar="K1,K2,P1,P2,K3",
        help="the camera lens's distortion (OpenCV's model; default none)",
    )
    p.add_argument(
        "--baseline",
        type=float,
        default=Rig.baseline_mm,
        metavar="MM",
        help="the projector this far to the camera's right (default %(default)s; 0 with --projector-below: above it)",
    )
    p.add_argument(
        "--orientation",
        choices=("vertical", "horizontal"),
        default="vertical",
        help="the fringes' way: vertical for a projector beside the camera, horizontal for one above or below",
    )
    p.add_argument(
        "--projector-below",
        type=float,
        default=Rig.projector_below_mm,
        metavar="MM",
        help="the projector this far down the camera's y axis (negative: above it; default 0, level with it)",
    )
    p.add_argument(
        "--projector-roll",
        type=float,
        default=Rig.projector_roll_deg,
        metavar="DEG",
        help="the projector turned about its own axis, its rows against the baseline (default 0)",
    )
    p.add_argument(
        "--board",
        metavar="COLSxROWS:SQUARE_MM",
        help="instead of a scene: --count poses of this checkerboard (inner corners) for fpp calibrate --board",
    )
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser(
        "calibrate", help="fit the phase-to-depth model from planes at known depths, or from a board at free poses"
    )
    p.add_argument(
        "planes",
        nargs="+",
        metavar="FOLDER:DEPTH_MM or POSE_FOLDER",
        help="fringe images of a plane square to the camera; with --board: a pose's folder "
        "(board.png, vertical/, horizontal/)",
    )
    p.add_argument(
        "--sensor",
        required=True,
        help="YAML with 'camera' intrinsics and 'patterns' (fpp simulate writes one; with --board only the "
        "camera's size and bits and the patterns are used); the camera's 'bits: 12' where a driver sends a "
        "12-bit camera's pixels as mono16",
    )
    p.add_argument(
        "--board",
        metavar="COLSxROWS:SQUARE_MM",
        help="calibrate camera and projector from this checkerboard (inner corners, square side in mm)",
    )
    p.add_argument("--lens", choices=tuple(LENS_MODELS), default="k1", help="with --board: the distortion terms fitted")
    p.add_argument("--reference-depth", type=float, default=None, help="background depth in mm (default: median plane)")
    p.add_argument(
        "--working-range",
        metavar="NEAR:FAR",
        help="depths in mm where surfaces may be; the single-shot path says NaN outside (default: the planes' "
        "or boards' depths)",
    )
    p.add_argument("--out", default="calibration.yaml")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("reconstruct", help="fringe images -> depth, point cloud, picture")
    p.add_argument("images", nargs="+", help="a folder of fringe_*.png/.tif, or the image files in projection order")
    p.add_argument("--calibration", required=True)
    p.add_argument(
        "--method",
        choices=("psp", "ftp", "cnn"),
        default="psp",
        help="psp: all images; ftp and cnn: one image (the calibration's single-shot frame: the "
        "composite, or the paper's first image of the highest frequency; cnn runs the "
        "single-shot network as cnn_depth does)",
    )
    p.add_argument("--model", help="with --method cnn: an ONNX model with its card (default: the shipped one)")
    p.add_argument(
        "--max-depth-noise",
        type=float,
        default=QualityLimits.max_depth_noise_mm,
        help="psp: keep pixels whose expected depth noise is at most this, mm",
    )
    p.add_argument(
        "--min-modulation",
        type=float,
        default=QualityLimits.min_modulation,
        help="ftp: keep pixels whose fringe lobe is at least this fraction of full scale",
    )
    p.add_argument("--max-depth-step", type=float, default=QualityLimits.max_depth_step_mm)
    p.add_argument(
        "--max-depth-bias",
        type=float,
        default=QualityLimits.max_depth_bias_mm,
        help="psp: largest depth a blurred albedo edge may move a kept pixel by, mm",
    )
    p.add_argument(
        "--truth",
        help="ground-truth depth in mm (.npy/.tiff) for error.png (default: the folder's "
        "depth_gt_mm.npy, as fpp simulate writes it)",
    )
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_reconstruct)

    p = sub.add_parser("evaluate", help="depth map vs ground truth")
    p.add_argument("prediction", help=".npy or float TIFF depth in mm")
    p.add_argument("truth", help=".npy or float TIFF depth in mm")
    p.add_argument("--valid", help="mask image of the ground truth's valid pixels")
    p.add_argument("--pictures", metavar="DIR", help="also write error.png, depth.png and profile.png there")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("demo", help="simulate, calibrate, reconstruct and evaluate end to end")
    p.add_argument("--out", default="out/demo")
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (ValueError, OSError) as e:  # every error of bad input is one of these
        print(f"fpp {args.command}: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
