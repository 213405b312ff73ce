"""Topic names, QoS profiles and frame ids, in one place.

Names are relative, so a namespace (ros2 run ... --ros-args -r __ns:=/left) moves them all.
QoS: multi-megabyte images and clouds are RELIABLE with a short KEEP_LAST history. Best-effort lost
most of them across processes with Fast DDS's default transports (`make bench-stream`: a BEST_EFFORT
subscriber got about a quarter of the 3.7 MB clouds; all of them with fastdds.xml beside this file,
but a subscriber may not have it; README, "The stream at 30 camera frames/s"), and a short history
means a slow subscriber sees the newest data rather than a growing backlog.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


class Topics:
    PATTERN = "projector/pattern"  # sensor_msgs/Image: the line of the pattern being shown, stamped when shown
    # sensor_msgs/Image: the same pattern, republished by projector_display stamped right after the flip
    # that put it on screen (remap capture_sequence's projector/pattern to it on a real rig)
    DISPLAYED = "projector/displayed"
    CAMERA_IMAGE = "camera/image_raw"  # sensor_msgs/Image: a fringe image (mono8 / mono16)
    CAMERA_INFO = "camera/camera_info"
    SEQUENCE = "fringe_sequence"  # sensor_msgs/Image: a complete sequence, K images stacked vertically
    SINGLE = "fringe_single"  # sensor_msgs/Image: of each complete sequence, the single-shot input image
    DEPTH = "depth/image"  # sensor_msgs/Image 32FC1, metres, NaN invalid
    DEPTH_INFO = "depth/camera_info"
    POINTS = "points"  # sensor_msgs/PointCloud2, organized, metres
    QUALITY = "quality/image"  # sensor_msgs/Image 32FC1: expected depth noise, millimetres, NaN invalid
    CONFIDENCE = "confidence/image"  # sensor_msgs/Image 32FC1: P(fringe order right), single shot
    TRUTH = "sim/depth_truth"  # sensor_msgs/Image 32FC1, metres: the simulator's exact depth
    CALIBRATION = "fpp/calibration"  # std_msgs/String, latched: calibration YAML (from a replayed bag)


class Frames:
    CAMERA = "camera_optical_frame"
    PROJECTOR = "projector_optical_frame"


class Qos:
    # Every image of a sequence matters; a few in flight cover DDS scheduling jitter.
    FRAMES = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=20,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )
    # Results and sequences: the newest matters, never a backlog.
    LARGE = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=2,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )
    # The newest value, kept for subscribers that join later (calibration, ground truth).
    LATCHED = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    # Camera info beside each image.
    INFO = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE)
