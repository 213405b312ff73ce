"""Message stamps as integer nanoseconds, the unit sequences and bags are keyed by."""

from std_msgs.msg import Header


def stamp_ns(stamp) -> int:
    """builtin_interfaces/Time (or rosbags' Time) -> nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def header_at(ns: int, frame_id: str = "") -> Header:
    header = Header(frame_id=frame_id)
    header.stamp.sec, header.stamp.nanosec = divmod(int(ns), 1_000_000_000)
    return header
