"""Board calibration against plane calibration on the simulated rig with a distorted camera lens.

For each draw of 15 board poses (default 9x7 inner corners, 8 mm squares; tilted 10-45 deg, 1100-1300 mm):
calibrate camera and projector from the board (fpp calibrate --board, each lens model), and compare
with the plane calibration (five planes on a stage, the camera's intrinsics known) on the same rig:
the worst pose's reprojection errors, the focal length's error, depth RMSE on two held-out scenes
(objects, sculpture) as calibrated and once the true focal length is given (each depth times true /
calibrated focal length: what is left when the focal length's scale is not the error), fringe-order
errors, and the flatness of a tilted plane filling the view (RMS about its best-fit plane, over the
noise the images alone cause there).

    python scripts/board_vs_plane.py [--draws 6]
    python scripts/board_vs_plane.py --focal 1500 --projector-field 700 --k1 -0.25 --board 9x7:25   # a 24-deg field
"""

from __future__ import annotations

import argparse

import numpy as np

from fpp_nodes.core.board import LENS_MODELS, Board, BoardPose, board_patterns, calibrate_from_board
from fpp_nodes.core.calibration import back_project
from fpp_nodes.core.metrics import ErrorTotals
from fpp_nodes.core.reconstruct import PspReconstructor
from fpp_nodes.core.scenes import board_poses, board_scene, make_scene, plane_scene
from fpp_nodes.core.simulation import Rig, render, render_pose
from fpp_nodes.core.workflow import fringe_depth_mm, simulated_calibration


def flatness_ratio(calibration, images) -> float:
    rec = PspReconstructor(calibration)(images)
    xyz = back_project(rec.depth_mm, calibration.camera).reshape(-1, 3).astype(np.float64)
    ok = np.isfinite(xyz).all(axis=1)
    a = np.c_[xyz[ok, :2], np.ones(ok.sum())]
    residual = xyz[ok, 2] - a @ np.linalg.lstsq(a, xyz[ok, 2], rcond=None)[0]
    return float(np.sqrt(np.mean(residual**2)) / np.sqrt(np.nanmean(rec.quality**2)))


def scores(calibration, scenes, plane_images, focal_px: float) -> str:
    """RMSE, the RMSE left once the focal length is given (every depth times true / calibrated focal
    length: depth scales with it), fringe-order errors and flatness."""
    errors, rescaled, orders = ErrorTotals(), ErrorTotals(), 0
    for capture in scenes:
        rec = PspReconstructor(calibration)(capture.images)
        truth = np.where(capture.valid, capture.depth_mm, np.nan)
        errors.add(rec.depth_mm, truth)
        rescaled.add(rec.depth_mm * (focal_px / calibration.camera.fx), truth)
        orders += ErrorTotals().add(rec.depth_mm, truth, fringe_depth_mm(calibration, rec.phase) / 2).over
    flatness = flatness_ratio(calibration, plane_images)
    return f"{errors.rmse:9.4f} {rescaled.rmse:10.4f} {orders:7d} {flatness:9.2f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--draws", type=int, default=3)
    parser.add_argument("--focal", type=float, default=Rig.focal_px, help="camera focal length, px")
    parser.add_argument("--projector-field", type=float, default=Rig.projector_field_mm, help="lit width at 1.2 m, mm")
    parser.add_argument("--k1", type=float, default=-0.9, help="the camera lens's radial k1 (p1, p2: 2e-4, -2e-4)")
    parser.add_argument("--board", default="9x7:8")
    args = parser.parse_args()
    lens, board = (args.k1, 0.0, 2e-4, -2e-4, 0.0), Board.parse(args.board)
    rig = Rig(focal_px=args.focal, projector_field_mm=args.projector_field, distortion=lens)
    patterns = rig.pattern_set()
    scenes = [
        render(rig, make_scene(rig, k, s), patterns, np.random.default_rng(s))
        for k, s in (("objects", 21), ("sculpture", 22))
    ]
    plane_images = render(rig, plane_scene(rig, 1200.0, tilt_x_deg=20.0), patterns, np.random.default_rng(5)).images
    planes, _ = simulated_calibration(rig, patterns, seed=7)
    print(f"rig: {rig.width}x{rig.height}, f {rig.focal_px:g} px, lens {lens}; board {args.board}")
    print(
        f"{'calibration':26} {'camera px':>9} {'proj px':>8} {'f error':>8} "
        f"{'RMSE mm':>9} {'f given':>10} {'orders':>7} {'flatness':>9}"
    )
    reference = scores(planes, scenes, plane_images, rig.focal_px)
    print(f"{'planes (stage, known K)':26} {'-':>9} {'-':>8} {'-':>8} {reference}")
    for draw in range(args.draws):
        rng = np.random.default_rng(100 + draw)
        poses = []
        for i, (rotation, translation) in enumerate(board_poses(rig, board, 15, rng)):
            scene = board_scene(rig, board, rotation, translation)
            image, stacks = render_pose(rig, scene, board_patterns(patterns), rng)
            poses.append(BoardPose(f"pose_{i:02d}", image, *stacks))
        for model in LENS_MODELS if draw == 0 else ("k1",):
            calibration, report = calibrate_from_board(poses, board, patterns, lens=model)
            camera_px = max(p.camera_px for p in report.poses)
            projector_px = max(p.projector_px for p in report.poses)
            f_error = calibration.camera.fx / rig.focal_px - 1
            print(
                f"{f'board, draw {draw}, lens {model}':26} {camera_px:9.3f} {projector_px:8.3f} {f_error:8.2%} "
                f"{scores(calibration, scenes, plane_images, rig.focal_px)}"
            )
    print(
        "camera px, proj px: the worst pose's RMS reprojection error; f error: the camera's focal length "
        "(the corners tell f/Z; every depth scales with f); "
        "RMSE and orders (pixels off by more than half a fringe's depth) over both held-out scenes; "
        "f given: the RMSE with every depth times true / calibrated focal length; "
        "flatness: a plane tilted 20 deg across the view, RMS about its best fit / the images' noise there"
    )


if __name__ == "__main__":
    main()
