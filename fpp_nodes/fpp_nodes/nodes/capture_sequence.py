"""capture_sequence: camera frames -> complete phase-shift sequences, using the projector's timing.

Subscribes projector/pattern (which pattern was shown when) and camera/image_raw. A frame belongs to
the pattern shown within max_time_offset of its stamp; its index comes from matching that pattern
against the calibration's pattern set. Publishes fringe_sequence (sensor_msgs/Image): the K frames
stacked vertically (height K x H), stamped with the first frame's time, and fringe_single: its
single-shot frame (the composite, its last frame; or with the paper's pattern set its first image of
the highest frequency), with that frame's stamp. A sequence with a missing,
duplicated or out-of-order frame is dropped with a warning and counted, never mixed into the next.
"""

from __future__ import annotations

import sys
from collections import deque

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Image

from fpp_msgs_py import ImageError, Qos, Topics, header_at, image_to_numpy, numpy_to_image, stamp_ns

from ..core.sequence import SequenceAssembler, ShownPatterns
from .common import check_positive, declare, describe, follow_calibration, load_calibration, on_set, run
from .health import Health


class CaptureSequence(Node):
    def __init__(self, **kwargs):
        super().__init__("capture_sequence", **kwargs)
        self.health = Health(self)
        self.max_offset_ns = int(
            declare(self, "max_time_offset", 0.005, "largest |camera stamp - pattern stamp| of a match, seconds") * 1e9
        )
        check_positive("max_time_offset", self.max_offset_ns)
        on_set(self, {"max_time_offset": check_positive})
        self.add_post_set_parameters_callback(
            lambda ps: [self._set_max_offset(int(p.value * 1e9)) for p in ps if p.name == "max_time_offset"]
        )
        self._use(*load_calibration(self))
        follow_calibration(self, lambda: self.calibration, lambda c: self._use(c, Topics.CALIBRATION))
        self.unmatched = 0
        self.publisher = self.create_publisher(Image, Topics.SEQUENCE, Qos.LARGE)
        self.single_publisher = self.create_publisher(Image, Topics.SINGLE, Qos.LARGE)
        self.create_subscription(Image, Topics.PATTERN, self._on_pattern, Qos.FRAMES)
        self.create_subscription(Image, Topics.CAMERA_IMAGE, self._on_frame, Qos.FRAMES)

    def _set_max_offset(self, ns: int):
        self.max_offset_ns = self.shown.max_offset_ns = ns

    def _use(self, calibration, source):
        patterns = calibration.patterns
        self.calibration = calibration
        self.health.facts["calibration"] = describe(calibration, source)
        self.shown = ShownPatterns(patterns, self.max_offset_ns)
        self.assembler = SequenceAssembler(patterns.count)
        self.waiting: deque[Image] = deque(maxlen=2 * patterns.count)  # frames that came before their pattern event

    def _on_pattern(self, msg: Image):
        try:
            index = self.shown.add(stamp_ns(msg.header.stamp), image_to_numpy(msg))
        except ImageError as e:
            self.health.report("patterns rejected", f"pattern ignored: {e}")
            return
        if index is None:
            self.health.report(
                "patterns rejected", "the projector shows a pattern that is not in the calibration's pattern set"
            )
            return
        self._drain()

    def _on_frame(self, msg: Image):
        self.health.count("frames in")
        if len(self.waiting) == self.waiting.maxlen:
            self._unmatched(self.waiting.popleft())
        self.waiting.append(msg)
        self._drain()

    def _drain(self):
        """Assemble waiting frames in arrival order; a frame waits until its pattern event arrives
        (the two topics are delivered independently) or a later event shows none will."""
        while self.waiting:
            head = self.waiting[0]
            match = self.shown.match(stamp_ns(head.header.stamp))
            if match is None:
                if not self.shown.none_will_match(stamp_ns(head.header.stamp)):
                    return
                self._unmatched(self.waiting.popleft())
                continue
            self._assemble(self.waiting.popleft(), *match)

    def _unmatched(self, frame: Image):
        self.unmatched += 1
        self.health.report(
            "frames matching no pattern",
            f"camera frame matches no projected pattern (within "
            f"{self.max_offset_ns / 1e9:g} s); {self.unmatched} so far",
        )

    def _assemble(self, msg: Image, index: int, showing: int):
        try:
            image = image_to_numpy(msg)
            check_frame(image, self.calibration.camera)
        except ImageError as e:
            # the sequence it belonged to is incomplete now and will be dropped, not mixed
            self.health.report("frames rejected", f"camera frame rejected: {e}")
            return
        sequence, dropped = self.assembler.add(index, stamp_ns(msg.header.stamp), image, showing)
        stats = self.assembler.stats
        if dropped:
            self.health.report(
                "sequences dropped",
                f"sequence dropped ({dropped}); {stats.dropped} dropped, {stats.completed} complete so far",
            )
        if sequence is None:
            return
        self.health.count("sequences complete")
        if self.publisher.get_subscription_count() > 0:  # no copy for nobody
            k, h, w = sequence.images.shape
            self.publisher.publish(
                numpy_to_image(sequence.images.reshape(k * h, w), header_at(sequence.stamps_ns[0], msg.header.frame_id))
            )
        if self.single_publisher.get_subscription_count() > 0:
            i = self.calibration.patterns.single_shot_index
            self.single_publisher.publish(
                numpy_to_image(sequence.images[i], header_at(sequence.stamps_ns[i], msg.header.frame_id))
            )

    def destroy_node(self):
        s = self.assembler.stats
        # printed, not logged: at shutdown rosout may already be gone
        print(
            f"[capture_sequence] frames in {s.frames_in}, sequences complete {s.completed}, dropped {s.dropped}"
            f"{' ' + str(s.reasons) if s.reasons else ''}, frames matching no pattern {self.unmatched}",
            file=sys.stderr,
            flush=True,
        )
        return super().destroy_node()


def check_frame(image: np.ndarray, camera) -> None:
    """A camera frame the multi-shot path can use: the calibration's size, finite if float."""
    if image.shape != camera.shape:
        raise ImageError(
            f"frame is {image.shape[1]}x{image.shape[0]}, the calibration's camera is {camera.width}x{camera.height}"
        )
    if image.dtype.kind == "f" and not np.isfinite(image).all():
        raise ImageError(f"{image.size - np.count_nonzero(np.isfinite(image))} pixels are NaN or Inf")


def main(args=None):
    run(CaptureSequence, args=args)


if __name__ == "__main__":
    main()
