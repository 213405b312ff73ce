"""fringe_camera_sim: the simulated camera. Sees the pattern the projector shows on a synthetic scene.

Subscribes projector/pattern (a fringe line or a full pattern image); publishes camera/image_raw
(mono8 or mono16) and camera/camera_info, stamped with the time of the pattern it captured, and
sim/depth_truth (32FC1, metres, NaN in projector shadow; latched) for evaluation. A real camera
driver or a bag replaces it.
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from fpp_msgs_py import Frames, ImageError, Qos, Topics, camera_info, image_to_numpy, numpy_to_image

from ..core.scenes import SCENE_KINDS, make_scene, scene_from_file
from ..core.simulation import Rig, SceneRenderer
from .common import declare, run
from .health import Health


class FringeCameraSim(Node):
    def __init__(self, **kwargs):
        super().__init__("fringe_camera_sim", **kwargs)
        self.health = Health(self)
        defaults = Rig()
        self.rig = Rig(
            noise_sigma=declare(self, "noise_sigma", defaults.noise_sigma, "camera noise, counts", True),
            blur_sigma_px=declare(self, "blur_sigma_px", defaults.blur_sigma_px, "defocus blur, pixels", True),
            projector_width=declare(self, "projector_width", defaults.projector_width, "pixels", True),
            projector_height=declare(self, "projector_height", defaults.projector_height, "pixels", True),
            projector_gamma=declare(self, "projector_gamma", defaults.projector_gamma, "", True),
            baseline_mm=declare(self, "baseline_mm", defaults.baseline_mm, "projector to the camera's right, mm", True),
            projector_below_mm=declare(
                self, "projector_below_mm", defaults.projector_below_mm, "projector down the camera's y axis, mm", True
            ),
            projector_roll_deg=declare(
                self, "projector_roll_deg", defaults.projector_roll_deg, "projector turned about its axis, deg", True
            ),
            distortion=tuple(
                declare(
                    self, "distortion", list(defaults.distortion), "camera lens k1, k2, p1, p2, k3 (OpenCV's)", True
                )
            ),
        )
        scene = declare(self, "scene", "sculpture", f"one of {', '.join(SCENE_KINDS)}, or a height map file (mm)", True)
        seed = declare(self, "seed", 0, "scene and noise seed", True)
        map_kind = declare(self, "map_kind", "height", "what a scene file holds: height or depth (mm)", True)
        self.scene = (
            make_scene(self.rig, scene, seed) if scene in SCENE_KINDS else scene_from_file(self.rig, scene, map_kind)
        )
        self.renderer = SceneRenderer(self.rig, self.scene)
        self.rng = np.random.default_rng(seed)
        cam = self.rig.camera()
        self.info = camera_info(**cam.to_dict())
        self.image_pub = self.create_publisher(Image, Topics.CAMERA_IMAGE, Qos.FRAMES)
        self.info_pub = self.create_publisher(CameraInfo, Topics.CAMERA_INFO, Qos.INFO)
        truth_pub = self.create_publisher(Image, Topics.TRUTH, Qos.LATCHED)
        truth = np.where(self.renderer.truth().valid, self.scene.depth_mm / 1000.0, np.nan).astype(np.float32)
        truth_pub.publish(numpy_to_image(truth, Header(stamp=self.get_clock().now().to_msg(), frame_id=Frames.CAMERA)))
        self.create_subscription(Image, Topics.PATTERN, self._on_pattern, Qos.FRAMES)
        self.get_logger().info(f"scene {self.scene.name} (seed {seed}), {cam.width}x{cam.height}")

    def _on_pattern(self, msg: Image):
        if self.image_pub.get_subscription_count() == 0:
            return  # nobody looks: render nothing
        try:
            pattern = image_to_numpy(msg)
        except ImageError as e:
            self.health.report("patterns rejected", f"pattern ignored: {e}")
            return
        w, h = self.rig.projector_width, self.rig.projector_height
        if pattern.shape not in ((1, w), (h, 1), (h, w)):
            self.health.report(
                "patterns rejected",
                f"pattern ignored: a {pattern.shape[1]}x{pattern.shape[0]} image is "
                f"neither a line nor the image of a {w}x{h} projector",
            )
            return
        image = self.renderer.image(pattern, 255 if pattern.dtype == np.uint8 else 65535, self.rng)
        header = Header(stamp=msg.header.stamp, frame_id=Frames.CAMERA)
        self.image_pub.publish(numpy_to_image(image, header))
        self.info.header = header
        self.info_pub.publish(self.info)
        self.health.count("frames out")


def main(args=None):
    run(FringeCameraSim, args=args)


if __name__ == "__main__":
    main()
