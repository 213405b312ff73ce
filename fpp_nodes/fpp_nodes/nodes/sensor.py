"""sensor: the whole simulated sensor in one process (projector, camera, capture, multi-shot depth),
each node as it runs alone, on one executor."""
from .capture_sequence import CaptureSequence
from .common import run
from .fpp_depth import FppDepth
from .fringe_camera_sim import FringeCameraSim
from .pattern_projector import PatternProjector


def main(args=None):
    run(PatternProjector, FringeCameraSim, CaptureSequence, FppDepth, args=args)


if __name__ == "__main__":
    main()
