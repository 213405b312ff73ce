"""Assembling camera frames into complete phase-shift sequences (no ROS here).

A frame is identified by the pattern the projector showed when it was taken: its index in the
pattern set. A sequence is the frames of indices 0 .. K-1, in order, with increasing stamps. A
missing, duplicated or out-of-order frame, a frame of another size or type, or time running
backwards (a camera that restarted) ends the sequence in progress: it is dropped, counted and the
reason returned, never mixed into the next one.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .patterns import PatternSet, pattern_images


def index_by_line(patterns: PatternSet) -> dict[bytes, int]:
    """Which pattern a projector shows, from the bytes of the image it published (patterns.pattern_images)."""
    return {image.tobytes(): i for i, image in enumerate(pattern_images(patterns))}


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

    def add(self, index: int, stamp_ns: int, image: np.ndarray) -> tuple[Sequence | None, str | None]:
        """Feed one frame. Returns (sequence, None) when it completes one, (None, reason) when it ends
        one in progress without completing it, else (None, None)."""
        self.stats.frames_in += 1
        dropped = None
        if self._stamps:
            expected = len(self._stamps)
            if stamp_ns <= self._stamps[-1]:
                dropped = self._drop(f"time went backwards: frame {index} stamped before frame {expected - 1} "
                                     f"(camera restarted?)")
            elif index == 0:
                dropped = self._drop(f"incomplete: a new sequence began after {expected} of {self.count} frames")
            elif index != expected:
                what = "duplicated" if index == expected - 1 else "missing" if index > expected else "out of order"
                dropped = self._drop(f"{what} frame: expected pattern {expected}, got {index}")
            elif image.shape != self._buffer.shape[1:] or image.dtype != self._buffer.dtype:
                dropped = self._drop(f"frame changed: {image.dtype} {image.shape} after "
                                     f"{self._buffer.dtype} {self._buffer.shape[1:]}")
        if not self._stamps:
            if index != 0:
                self.stats.frames_discarded += 1  # mid-sequence: wait for the next start
                return None, dropped
            if self._buffer is None or self._buffer.shape[1:] != image.shape or self._buffer.dtype != image.dtype:
                self._buffer = np.empty((self.count,) + image.shape, image.dtype)
        self._buffer[len(self._stamps)] = image
        self._stamps.append(stamp_ns)
        if len(self._stamps) < self.count:
            return None, dropped
        done = Sequence(self._buffer, self._stamps)
        self._buffer, self._stamps = None, []
        self.stats.completed += 1
        return done, dropped
