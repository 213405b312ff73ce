"""fpp_depth: the multi-shot path. Each complete fringe sequence -> depth, point cloud, quality.

Subscribes fringe_sequence (K images stacked vertically). Publishes depth/image (32FC1, metres, NaN
invalid), depth/camera_info, points (organized PointCloud2, metres, optical frame) and quality/image
(32FC1, each pixel's expected depth noise in millimetres: its phase noise, estimated from the residual of
the N-step fit, through the calibration's dz/dphi; NaN invalid), each with the sequence's header. Outputs nobody
subscribes to are not computed; with no subscriber at all, nothing is. Every CHECK_PERIOD_S, on a thread beside
the stream, it checks that the rig still fits its calibration (reconstruct.CodeFit, where the sequences end with
the composite frame): a misfit over MAX_CODE_MISFIT_RAD is a warning on /diagnostics for every sequence until a
later check passes.
"""

from __future__ import annotations

import threading
import time

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from fpp_msgs_py import ImageError, Qos, Topics, image_to_numpy, numpy_to_image, xyz_to_cloud

from ..core.calibration import CalibrationError
from ..core.phase import PhaseError
from ..core.reconstruct import MAX_CODE_MISFIT_RAD, CodeFit, PspReconstructor, QualityLimits
from .common import camera_info_of, declare, describe, follow_calibration, load_calibration, run, warn_if_narrow
from .health import Health

CHECK_PERIOD_S = 10.0  # a check takes about 0.1 s of the other core


class FppDepth(Node):
    def __init__(self, **kwargs):
        super().__init__("fpp_depth", **kwargs)
        self.health = Health(self)
        calibration, source = load_calibration(self)
        self.limits = QualityLimits(
            max_depth_noise_mm=declare(
                self,
                "max_depth_noise_mm",
                QualityLimits.max_depth_noise_mm,
                "largest expected depth noise kept (quality/image), mm",
                True,
            ),
            max_depth_step_mm=declare(
                self,
                "max_depth_step_mm",
                QualityLimits.max_depth_step_mm,
                "largest depth step between neighbours kept (flying pixels), mm",
                True,
            ),
            max_depth_bias_mm=declare(
                self,
                "max_depth_bias_mm",
                QualityLimits.max_depth_bias_mm,
                "largest depth a blurred albedo edge may move a pixel by and it is kept, mm",
                True,
            ),
        )
        self._use(calibration, source)
        follow_calibration(self, lambda: self.calibration, lambda c: self._use(c, Topics.CALIBRATION))
        self.depth_pub = self.create_publisher(Image, Topics.DEPTH, Qos.LARGE)
        self.info_pub = self.create_publisher(CameraInfo, Topics.DEPTH_INFO, Qos.INFO)
        self.points_pub = self.create_publisher(PointCloud2, Topics.POINTS, Qos.LARGE)
        self.quality_pub = self.create_publisher(Image, Topics.QUALITY, Qos.LARGE)
        self.create_subscription(Image, Topics.SEQUENCE, self._on_sequence, Qos.LARGE)

    def _use(self, calibration, source):
        self.calibration = calibration
        composite = calibration.patterns.single_shot == "composite" and bool(calibration.code_models)
        self.code_fit, self.misfit, self.checked = (CodeFit(calibration) if composite else None), 0.0, -np.inf
        self.health.facts["calibration"] = describe(calibration, source)
        self.reconstruct = PspReconstructor(calibration, self.limits)
        cam = calibration.camera
        # compiles the path's kernels (or loads them from numba's cache) now, not on the first sequence
        self.reconstruct(np.zeros((calibration.patterns.count, cam.height, cam.width), cam.frame_dtype))
        self.info = camera_info_of(cam)

    def _wanted(self):
        return {
            name: pub.get_subscription_count() > 0
            for name, pub in (("depth", self.depth_pub), ("points", self.points_pub), ("quality", self.quality_pub))
        }

    def _on_sequence(self, msg: Image):
        self.health.count("sequences in")
        wanted = self._wanted()
        if not any(wanted.values()):
            self.health.count("sequences skipped (no subscribers)")
            return
        start = time.perf_counter()
        cam, k = self.calibration.camera, self.calibration.patterns.count
        try:
            stack = image_to_numpy(msg)
            if stack.shape != (k * cam.height, cam.width):
                raise ImageError(
                    f"expected {k} stacked {cam.width}x{cam.height} images ({cam.width}x{k * cam.height}), "
                    f"got {stack.shape[1]}x{stack.shape[0]}"
                )
            rec = self.reconstruct(stack.reshape(k, cam.height, cam.width))
        except (ImageError, PhaseError, CalibrationError) as e:
            self.health.report("sequences rejected", f"sequence rejected: {e}")
            return
        warn_if_narrow(self.health, cam, stack[: cam.height])  # one frame tells: the sequence's first
        header = msg.header
        if wanted["depth"]:
            self.depth_pub.publish(numpy_to_image(rec.depth_mm * np.float32(0.001), header))
        if wanted["points"]:
            self.points_pub.publish(xyz_to_cloud(rec.xyz_mm * np.float32(0.001), header))
        if wanted["quality"]:
            self.quality_pub.publish(numpy_to_image(rec.quality, header))
        self.info.header = header
        self.info_pub.publish(self.info)
        self.health.count("depth out")
        self.health.latency(time.perf_counter() - start)
        self.health.usable_pixels(np.count_nonzero(rec.valid) / rec.valid.size, "sequences without fringes")
        # a focus monitor: the defocus the fringes show (camera and projector), which the bias rule reads
        self.health.fact("fringe blur (last)", f"{rec.blur_px:.2f} px")
        self._check_fit(stack.reshape(k, cam.height, cam.width), rec)

    def _check_fit(self, images, rec):
        """Start a check of the rig against its calibration every CHECK_PERIOD_S (on a thread of its own, with
        copies of what it reads); say so with every sequence while the last one failed."""
        if self.misfit > MAX_CODE_MISFIT_RAD:
            self.health.report(
                "sequences from a rig that no longer fits its calibration",
                f"the composite frame's codes miss the calibration's by {self.misfit:.2f} rad (at most "
                f"{MAX_CODE_MISFIT_RAD} as calibrated): has the projector been turned or moved since? Depth may be "
                "off (0.3 mm at a roll of 0.1 degree, more beyond): calibrate again",
            )
        if self.code_fit is None or time.monotonic() - self.checked < CHECK_PERIOD_S:
            return
        self.checked = time.monotonic()
        frame = images[self.calibration.patterns.single_shot_index].copy()
        depth, phase, fit = rec.depth_mm.copy(), rec.phase.copy(), self.code_fit

        def check():
            misfit = fit(frame, depth, phase)
            if fit is self.code_fit and np.isfinite(misfit):  # not a calibration since replaced
                self.misfit = misfit
                self.health.fact("codes' misfit to the calibration (last check)", f"{misfit:.3f} rad")

        threading.Thread(target=check, daemon=True).start()


def main(args=None):
    run(FppDepth, args=args)


if __name__ == "__main__":
    main()
