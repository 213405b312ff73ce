"""sensor: the whole simulated sensor in one process, each node as it runs alone: on one executor
pattern_projector -> fringe_camera_sim -> capture_sequence -> fpp_depth (multi-shot: depth/image,
points) and, side by side on an executor of its own (common.spin), cnn_depth in the cnn namespace
(single-shot on each sequence's fringe_single image: cnn/depth/image, cnn/points)."""

from .capture_sequence import CaptureSequence
from .cnn_depth import CnnDepth
from .common import run
from .fpp_depth import FppDepth
from .fringe_camera_sim import FringeCameraSim
from .pattern_projector import PatternProjector


def single_shot() -> CnnDepth:
    # the composed demo lives at the root namespace; run the nodes alone to place them elsewhere. A
    # replayed bag's calibration comes on /fpp/calibration, for every node of the sensor
    remaps = ["camera/image_raw:=/fringe_single", "fpp/calibration:=/fpp/calibration"]
    return CnnDepth(namespace="cnn", cli_args=["--ros-args", *(a for r in remaps for a in ("-r", r))])


def projector() -> PatternProjector:
    node = PatternProjector()
    if node.single_shot_only:  # no sequence would ever complete: say so rather than publish nothing
        node.destroy_node()
        raise ValueError(
            "single_shot_only: the composed sensor runs whole sequences; for a single-shot sensor run "
            "pattern_projector (single_shot_only:=true), fringe_camera_sim and cnn_depth (docs/using-the-sensor.md)"
        )
    return node


def main(args=None):
    run(projector, FringeCameraSim, CaptureSequence, FppDepth, single_shot, args=args)


if __name__ == "__main__":
    main()
