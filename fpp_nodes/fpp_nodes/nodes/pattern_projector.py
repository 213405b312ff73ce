"""pattern_projector: shows the pattern set, one pattern per tick, and says which and when.

Publishes projector/pattern (sensor_msgs/Image): a phase-shift pattern as its profile across the
fringes (1 x L for vertical fringes, L x 1 for horizontal), the single-shot composite (the last frame
of each sequence, unless single_shot:=paper) as the full image, stamped with the time it is shown. Continuously
by default; with continuous:=false, each call of ~/capture (std_srvs/Trigger) shows one sequence. With
single_shot_only:=true it shows the single-shot frame alone on every tick, a sequence of one: a single-shot
sensor (cnn_depth on camera/image_raw) at the camera's rate instead of once a sequence.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time
from rclpy.node import Node
from sensor_msgs.msg import Image
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from fpp_msgs_py import Frames, Qos, Topics, numpy_to_image

from ..core.patterns import SINGLE_SHOT_KINDS, PatternSet, pattern_images
from .common import check_positive, declare, on_set, run
from .health import Health


class PatternProjector(Node):
    def __init__(self, **kwargs):
        super().__init__("pattern_projector", **kwargs)
        self.health = Health(self)
        self.patterns = PatternSet(
            frequencies=tuple(
                declare(self, "frequencies", [1, 4, 20, 100], "fringes across the pattern, increasing from 1", True)
            ),
            steps=declare(self, "steps", 4, "phase shifts per frequency (>= 3)", True),
            width=declare(self, "width", 1280, "projector width, pixels", True),
            height=declare(self, "height", 800, "projector height, pixels", True),
            orientation=declare(self, "orientation", "vertical", "vertical or horizontal fringes", True),
            bit_depth=declare(self, "bit_depth", 8, "8 or 16", True),
            gamma=declare(self, "gamma", 2.2, "projector gamma the patterns pre-compensate", True),
            single_shot=declare(
                self,
                "single_shot",
                "composite",
                f"single-shot frame: {' or '.join(SINGLE_SHOT_KINDS)} "
                "(composite: one more frame; paper: the first step of the highest frequency)",
                True,
            ),
        )
        self.rate = declare(self, "rate", 30.0, "patterns per second")
        check_positive("rate", self.rate)
        self.continuous = declare(
            self, "continuous", True, "show sequences over and over; false: one per ~/capture call"
        )
        self.single_shot_only = single_shot_only = declare(
            self,
            "single_shot_only",
            False,
            "show the single-shot frame alone on every tick (cnn_depth at the camera's rate; no multi-shot depth)",
            True,
        )
        on_set(self, {"rate": check_positive})
        self.add_post_set_parameters_callback(self._after_set)
        self.lines = pattern_images(self.patterns)
        if single_shot_only:
            self.lines = [self.lines[self.patterns.single_shot_index]]
        self.publisher = self.create_publisher(Image, Topics.PATTERN, Qos.FRAMES)
        self.create_service(Trigger, "~/capture", self._on_capture)
        self.index = 0
        self.queued = 0
        self.timer = self.create_timer(1.0 / self.rate, self._on_tick)
        shown = "the single-shot frame alone" if single_shot_only else f"{len(self.lines)} patterns"
        when = "continuous" if self.continuous else "on ~/capture"
        self.get_logger().info(f"{shown} at {self.rate:g} Hz, {when}")

    def _after_set(self, params):
        for p in params:
            if p.name == "rate":
                self.rate = p.value
                self.timer.cancel()
                self.timer = self.create_timer(1.0 / self.rate, self._on_tick)
            elif p.name == "continuous":
                self.continuous = p.value

    def _on_capture(self, request, response):
        self.queued += 1
        response.success = True
        response.message = f"{self.queued} sequence(s) queued"
        return response

    def _on_tick(self):
        if not self.continuous and self.index == 0:
            if self.queued == 0:
                return
            self.queued -= 1
        stamp: Time = self.get_clock().now().to_msg()
        self.publisher.publish(numpy_to_image(self.lines[self.index], Header(stamp=stamp, frame_id=Frames.PROJECTOR)))
        self.health.count("patterns shown")
        self.index = (self.index + 1) % len(self.lines)


def main(args=None):
    run(PatternProjector, args=args)


if __name__ == "__main__":
    main()
