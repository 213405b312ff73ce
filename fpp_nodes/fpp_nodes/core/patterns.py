"""Fringe patterns, the paper's equation (1).

    I_j(u, v) = I_0 [1 + cos(phi + delta_j)],   phi = 2 pi f x / L,   delta_j = 2 pi j / N

x is the projector column (vertical fringes) or row (horizontal fringes), L the projector width or
height, f the number of fringes across the pattern, N the number of phase-shift steps.
"""
from __future__ import annotations

from dataclasses import dataclass, asdict

import numpy as np


class PatternError(ValueError):
    """A pattern set that cannot be projected or decoded."""


@dataclass(frozen=True)
class PatternSet:
    """What the projector shows, in order: every step of the first frequency, then the next frequency.

    gamma pre-compensates the projector's response (radiance = value ** gamma), so that the light on
    the scene is sinusoidal; 1.0 for a linear projector.
    """

    frequencies: tuple[int, ...] = (1, 4, 20, 100)
    steps: int = 4
    width: int = 1280
    height: int = 800
    orientation: str = "vertical"
    bit_depth: int = 8
    gamma: float = 2.2

    def __post_init__(self):
        object.__setattr__(self, "frequencies", tuple(int(f) for f in self.frequencies))
        validate_pattern_set(self)

    @property
    def count(self) -> int:
        return len(self.frequencies) * self.steps

    @property
    def period_axis_length(self) -> int:
        """L of equation (1): the projector extent across the fringes."""
        return self.width if self.orientation == "vertical" else self.height

    @property
    def max_value(self) -> int:
        return (1 << self.bit_depth) - 1

    @property
    def single_shot_index(self) -> int:
        """Which pattern the single-shot path sees: the first step of the highest frequency (the paper's input)."""
        return (len(self.frequencies) - 1) * self.steps

    def shifts(self) -> np.ndarray:
        """delta_j = 2 pi j / N for j = 0 .. N-1."""
        return 2.0 * np.pi * np.arange(self.steps) / self.steps

    def order(self) -> list[tuple[int, int]]:
        """(frequency, step) of each pattern in projection order."""
        return [(f, j) for f in self.frequencies for j in range(self.steps)]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["frequencies"] = list(self.frequencies)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "PatternSet":
        try:
            return cls(**d)
        except TypeError as e:
            raise PatternError(f"pattern set: {e}") from None


def validate_pattern_set(p: PatternSet) -> None:
    """Raise PatternError naming the first problem found."""
    if p.steps < 3:
        raise PatternError(f"steps must be >= 3 (three unknowns per pixel), got {p.steps}")
    if not p.frequencies:
        raise PatternError("frequencies must not be empty")
    if p.frequencies[0] != 1:
        raise PatternError(f"the first frequency must be 1 (one fringe gives absolute phase), got {p.frequencies[0]}")
    if any(b <= a for a, b in zip(p.frequencies, p.frequencies[1:])):
        raise PatternError(f"frequencies must be strictly increasing, got {list(p.frequencies)}")
    if p.width < 2 or p.height < 2:
        raise PatternError(f"projector resolution must be at least 2x2, got {p.width}x{p.height}")
    if p.orientation not in ("vertical", "horizontal"):
        raise PatternError(f"orientation must be 'vertical' or 'horizontal', got {p.orientation!r}")
    if p.bit_depth not in (8, 16):
        raise PatternError(f"bit_depth must be 8 or 16, got {p.bit_depth}")
    if 2 * p.frequencies[-1] > p.period_axis_length:
        raise PatternError(
            f"{p.frequencies[-1]} fringes need at least {2 * p.frequencies[-1]} projector pixels, "
            f"the pattern has {p.period_axis_length}")
    if not p.gamma > 0:
        raise PatternError(f"gamma must be > 0, got {p.gamma}")


def fringe_value(p: PatternSet, frequency: int, step: int, x: np.ndarray) -> np.ndarray:
    """Pattern value at projector coordinate(s) x (may be fractional), quantized to the bit depth.

    Equation (1) with I_0 = max/2, pre-compensated by 1/gamma.
    """
    phase = 2.0 * np.pi * frequency * np.asarray(x, dtype=np.float64) / p.period_axis_length
    radiance = 0.5 * (1.0 + np.cos(phase + p.shifts()[step]))
    return np.round(p.max_value * radiance ** (1.0 / p.gamma))


def pattern_dtype(p: PatternSet):
    return np.uint8 if p.bit_depth == 8 else np.uint16


def pattern_lines(p: PatternSet) -> np.ndarray:
    """Every pattern's profile across the fringes, shape (count, L): a pattern is its line repeated
    along the fringes, so the line is all a projector or a simulated camera needs."""
    x = np.arange(p.period_axis_length)
    return np.stack([fringe_value(p, f, j, x) for f, j in p.order()]).astype(pattern_dtype(p))


def line_image(p: PatternSet, line: np.ndarray) -> np.ndarray:
    """The pattern as the 2-D image a projector shows: 1 x L for vertical fringes, L x 1 for horizontal
    (broadcast it to height x width to display)."""
    return line[None, :] if p.orientation == "vertical" else line[:, None]


def generate_patterns(p: PatternSet) -> np.ndarray:
    """All patterns, shape (count, height, width), uint8 or uint16, in projection order."""
    return np.stack([np.broadcast_to(line_image(p, line), (p.height, p.width)) for line in pattern_lines(p)])
