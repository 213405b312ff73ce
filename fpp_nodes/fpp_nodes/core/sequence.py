"""Assembling camera frames into complete phase-shift sequences (no ROS here).

A frame is identified by the pattern the projector showed when it was taken (ShownPatterns): its
index in the pattern set, and which showing it was (the projector's running count). A sequence is the
frames of indices 0 .. K-1, of consecutive showings, with increasing stamps. A missing, duplicated or
out-of-order frame, a gap of whole cycles (a camera that was away for a while), a frame of another
size or type, or time running backwards (a camera that restarted) ends the sequence in progress: it
is dropped, counted and the reason returned, never mixed into the next one.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .patterns import PatternSet, pattern_images


class ShownPatterns:
    """What the projector showed when, from the pattern images it published, and so which pattern a
    camera frame saw: the one shown closest to the frame's stamp, within max_offset_ns. The node and
    the bag reader both match frames this way."""

    def __init__(self, patterns: PatternSet, max_offset_ns: int):
        self.index_of_bytes = {image.tobytes(): i for i, image in enumerate(pattern_images(patterns))}
        self.max_offset_ns = max_offset_ns
        self.events: deque[tuple[int, int, int]] = deque(maxlen=4 * patterns.count)  # (stamp ns, index, showing)
        self.showings = 0  # patterns of the set shown so far

    def add(self, stamp_ns: int, pattern_image: np.ndarray) -> int | None:
        """Note a shown pattern; its index, or None for an image not in the pattern set (not noted)."""
        index = self.index_of_bytes.get(pattern_image.tobytes())
        if index is not None:
            self.events.append((stamp_ns, index, self.showings))
            self.showings += 1
        return index

    def match(self, frame_stamp_ns: int) -> tuple[int, int] | None:
        """(pattern index, showing number) of the pattern a frame stamped frame_stamp_ns saw, or None if
        none was shown near it."""
        best = min(self.events, key=lambda e: abs(e[0] - frame_stamp_ns), default=None)
        return best[1:] if best is not None and abs(best[0] - frame_stamp_ns) <= self.max_offset_ns else None

    def none_will_match(self, frame_stamp_ns: int) -> bool:
        """True when a pattern was shown after the frame's window closed, so no later event can match it."""
        return bool(self.events) and self.events[-1][0] > frame_stamp_ns + self.max_offset_ns


@dataclass
class SequenceStats:
    completed: int = 0
    dropped: int = 0
    frames_in: int = 0
    frames_discarded: int = 0  # frames not used: part of a dropped sequence, or waiting for index 0
    reasons: dict = field(default_factory=dict)


@dataclass
class Sequence:
    images: np.ndarray  # (K, H, W), owned by the caller from now on
    stamps_ns: list[int]


class SequenceAssembler:
    def __init__(self, count: int):
        if count < 3:
            raise ValueError(f"a sequence needs at least 3 frames, got {count}")
        self.count = count
        self.stats = SequenceStats()
        self._buffer: np.ndarray | None = None
        self._stamps: list[int] = []
        self._showing: int | None = None  # the showing the last frame saw

    @property
    def in_progress(self) -> int:
        return len(self._stamps)

    def _drop(self, reason: str) -> str:
        self.stats.dropped += 1
        self.stats.frames_discarded += len(self._stamps)
        kind = reason.split(":")[0]
        self.stats.reasons[kind] = self.stats.reasons.get(kind, 0) + 1
        self._stamps = []
        return reason

    def add(
        self, index: int, stamp_ns: int, image: np.ndarray, showing: int | None = None
    ) -> tuple[Sequence | None, str | None]:
        """Feed one frame (showing: which showing of its pattern it saw, ShownPatterns.match; None: not
        known). Returns (sequence, None) when it completes one, (None, reason) when it ends one in
        progress without completing it, else (None, None)."""
        self.stats.frames_in += 1
        dropped = None
        if self._stamps:
            expected = len(self._stamps)
            if stamp_ns <= self._stamps[-1]:
                dropped = self._drop(
                    f"time went backwards: frame {index} stamped before frame {expected - 1} (camera restarted?)"
                )
            elif showing is not None and self._showing is not None and showing > self._showing + 1:
                dropped = self._drop(f"missing frames: {showing - self._showing - 1} patterns shown without one")
            elif index == 0:
                dropped = self._drop(f"incomplete: a new sequence began after {expected} of {self.count} frames")
            elif index != expected:
                what = "duplicated" if index == expected - 1 else "missing" if index > expected else "out of order"
                dropped = self._drop(f"{what} frame: expected pattern {expected}, got {index}")
            elif image.shape != self._buffer.shape[1:] or image.dtype != self._buffer.dtype:
                dropped = self._drop(
                    f"frame changed: {image.dtype} {image.shape} after {self._buffer.dtype} {self._buffer.shape[1:]}"
                )
        if not self._stamps:
            if index != 0:
                self.stats.frames_discarded += 1  # mid-sequence: wait for the next start
                return None, dropped
            if self._buffer is None or self._buffer.shape[1:] != image.shape or self._buffer.dtype != image.dtype:
                self._buffer = np.empty((self.count,) + image.shape, image.dtype)
        self._buffer[len(self._stamps)] = image
        self._stamps.append(stamp_ns)
        self._showing = showing
        if len(self._stamps) < self.count:
            return None, dropped
        done = Sequence(self._buffer, self._stamps)
        self._buffer, self._stamps = None, []
        self.stats.completed += 1
        return done, dropped
