"""cnn_depth: the single-shot path. One fringe image -> depth and point cloud through a trained
network (ONNX, run with onnxruntime).

Subscribes camera/image_raw (mono8/mono16: the single-shot frame the model was trained on, its
card's pattern set: the composite by default, the paper's first image of the highest frequency for
the paper's networks; a calibration whose pattern set differs stops the node at start), keeping only
the newest frame (KEEP_LAST 1): under load older frames are dropped, never queued beyond the one
that may wait for the decoding (below). Publishes
depth/image (32FC1, metres, NaN where the image shows no usable fringes: shadows, dark or saturated
areas), depth/camera_info and points (organized PointCloud2, metres), with the image's header, and
its health on /diagnostics (the latency from image in to outputs published, and its two stages, network
and decode and publish, p50 and p95; for the composite model also the share of the pixels with fringes
whose codes name no order of the calibration's working range, a warning when 30% do or when the decoder
refuses 1% for codes that repeat beyond it: DepthModel.warnings). A phase-aware model
also gives confidence/image (32FC1, 0-1: for the composite model the share of the pixels around it,
and of its whole surface, whose codes give the order chosen there, the lesser of the two; for the
paper-pattern phase model the probability that the order is right; depth is NaN below the threshold
its card holds, and within its card's margin of a pixel refused so, both chosen on validation data).
A frame of the wrong size or encoding is rejected and counted; a missing, corrupt or mismatched
model stops the node at start. Parameters: model (path; empty = the shipped default), providers
(CPUExecutionProvider; CUDA where present), threads (onnxruntime intra-op threads), min_confidence
(negative: the model card's), calibration (the rig's: a composite model's phases become depth
through it, whatever rig trained the network; intrinsics for the cloud).

Up to three frames are in hand at once: the network runs on a frame in the subscription's callback
while a thread of the node's own decodes an earlier one and publishes it, with at most one more
between them, so on 2 cores the network takes one (threads 1, the default) and the decoding the other
(docs/single-shot.md, the node's speed), and neither waits on the other's slower frames. The network's
thread, the busier, hands its outputs over as the network gives them; only where it would otherwise
wait does it lay them out (DepthModel.laid_out) and take the frame's code sidebands itself.
"""

from __future__ import annotations

import queue
import threading
import time

import numpy as np
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from fpp_msgs_py import ImageError, Qos, Topics, image_to_numpy, numpy_to_image, xyz_to_cloud

from ..core.calibration import CalibrationError, back_project
from ..core.model import DepthModel, ModelError, default_model_path
from .common import camera_info_of, declare, describe, follow_calibration, load_calibration, run, warn_if_narrow
from .health import Health

NETWORK_THREADS = 1  # the default: the network on one core, the decoding of earlier frames on the other
NEWEST_ONLY = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE)


class CnnDepth(Node):
    LONG_CALLBACKS = True  # the network runs in the image callback: beside other nodes, an executor of its own

    def __init__(self, **kwargs):
        super().__init__("cnn_depth", **kwargs)
        path = declare(self, "model", "", "ONNX model with its card beside it (empty: the shipped default)", True)
        providers = declare(self, "providers", ["CPUExecutionProvider"], "onnxruntime execution providers", True)
        threads = declare(
            self,
            "threads",
            NETWORK_THREADS,
            "onnxruntime intra-op threads (the decoding of earlier frames runs beside them; 2: lower latency "
            "where the cores have time to spare, fewer frames at most)",
            True,
        )
        min_confidence = declare(
            self,
            "min_confidence",
            -1.0,
            "a phase-aware model's order confidence below which "
            "depth is NaN (negative: its card's, chosen on validation data; 0 still refuses confidence 0)",
            True,
        )
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        if min_confidence > 1.0:
            raise ValueError(f"min_confidence must be <= 1 (negative: the model card's), got {min_confidence}")
        self.health = Health(self)
        calibration, source = load_calibration(self)
        path = path or default_model_path()
        self.model = DepthModel(path, providers, threads, calibration)
        if min_confidence >= 0 and self.model.decoder is not None:
            self.model.min_confidence = min_confidence
        # the network's outputs to the decoding thread: one frame may wait there while it decodes another,
        # so that neither thread waits on the other's slower frames; the next waits in the subscription,
        # which keeps only the newest
        self.decoding = queue.Queue(maxsize=1)
        self._use(calibration, source)
        follow_calibration(self, lambda: self.calibration, lambda c: self._use(c, Topics.CALIBRATION))
        started = time.monotonic()
        self.get_logger().info("warming up: the first start after an install compiles the decoding (about 7 s)")
        self.model.warm_up()
        self.depth_pub = self.create_publisher(Image, Topics.DEPTH, Qos.LARGE)
        self.info_pub = self.create_publisher(CameraInfo, Topics.DEPTH_INFO, Qos.INFO)
        self.points_pub = self.create_publisher(PointCloud2, Topics.POINTS, Qos.LARGE)
        self.confidence_pub = self.create_publisher(Image, Topics.CONFIDENCE, Qos.LARGE)
        self.create_subscription(Image, Topics.CAMERA_IMAGE, self._on_image, NEWEST_ONLY)
        card = self.model.card
        self.health.facts.update(
            {
                "model": path,
                "model sha256": card["sha256"][:12],
                "architecture": str(card.get("architecture")),
                "providers": ", ".join(self.model.providers),
            }
        )
        self.get_logger().info(
            f"model {path} ({card.get('architecture')}), providers {self.model.providers}; ready after "
            f"{time.monotonic() - started:.1f} s of warm-up"
        )
        self.decoder_thread = threading.Thread(target=self._decode_frames, name="cnn_depth decoding", daemon=True)
        self.decoder_thread.start()

    def _use(self, calibration, source):
        """The rig's calibration (a replayed bag's, from fpp/calibration): a composite model's depth and
        every cloud from the next frame on; the frame in hand is published with the one before."""
        self.decoding.join()  # one executor thread: no frame is queued until this returns
        self.model.use(calibration)
        self.calibration, self.info = calibration, camera_info_of(calibration.camera)
        self.health.facts["calibration"] = describe(calibration, source)

    def _on_image(self, msg: Image):
        self.health.count("frames in")
        want = {
            "depth": self.depth_pub.get_subscription_count() > 0,
            "points": self.points_pub.get_subscription_count() > 0,
            "confidence": self.confidence_pub.get_subscription_count() > 0,
        }
        if not any(want.values()):
            self.health.count("frames skipped (no subscribers)")
            return
        start = time.perf_counter()
        try:
            image = self.model.frame(image_to_numpy(msg))
            raw = self.model.network(image)
            self.health.latency(time.perf_counter() - start, "network")
        except (ImageError, ModelError, CalibrationError) as e:
            self.health.report("frames rejected", f"image rejected: {e}")
            return
        warn_if_narrow(self.health, self.calibration.camera, image)
        out = sidebands = None
        if self.decoding.full():  # this thread would only wait: it lays the outputs out and takes the sidebands
            out = self.model.laid_out(raw)
            sidebands = self.model.sidebands(image, out)
        self.decoding.put((msg.header, image, raw, out, sidebands, want, start))

    def _decode_frames(self):
        while (frame := self.decoding.get()) is not None:
            try:
                self._publish(*frame)
            except Exception as e:  # a bug must not stop the thread: say so and go on with the next frame
                if self.context.ok():  # not a publish that lost the race with shutting down
                    self.health.report("frames failed", f"decoding failed: {type(e).__name__}: {e}")
            finally:
                self.decoding.task_done()

    def _publish(self, header, image, raw, out, sidebands, want, start):
        decoding = time.perf_counter()
        out = self.model.laid_out(raw) if out is None else out
        depth_mm, confidence = self.model.decode(image, out, sidebands)
        if want["depth"]:
            self.depth_pub.publish(numpy_to_image(depth_mm * np.float32(0.001), header))
        if want["confidence"] and confidence is not None:
            self.confidence_pub.publish(numpy_to_image(confidence, header))
        if want["points"]:
            self.points_pub.publish(
                xyz_to_cloud(back_project(depth_mm, self.calibration.camera) * np.float32(0.001), header)
            )
        self.info.header = header
        self.info_pub.publish(self.info)
        self.health.count("depth out")
        published = time.perf_counter()
        self.health.latency(published - start)
        self.health.latency(published - decoding, "decode and publish")
        # usable: pixels that show fringes (a phase-aware model's confidence is NaN elsewhere); a pixel
        # with fringes whose order is unsure is no fault of the input
        usable = depth_mm if confidence is None else confidence
        self.health.usable_pixels(np.count_nonzero(np.isfinite(usable)) / usable.size, "frames without fringes")
        if confidence is not None:
            self.health.fact("depth given (last)", f"{np.count_nonzero(np.isfinite(depth_mm)) / depth_mm.size:.1%}")
        outside = getattr(self.model.decoder, "outside_range", None)  # a composite model's
        if outside is not None:
            self.health.fact("fringes outside the working range (last)", f"{outside:.1%}")
        for frames, warning in self.model.warnings().items():
            self.health.report(frames, warning)

    def destroy_node(self):
        if self.decoder_thread.is_alive():
            self.decoding.put(None)  # after the frame in hand
            self.decoder_thread.join(timeout=10)
        return super().destroy_node()


def main(args=None):
    run(CnnDepth, args=args)


if __name__ == "__main__":
    main()
