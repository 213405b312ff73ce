"""Fringe patterns, the paper's equation (1).

    I_j(u, v) = I_0 [1 + cos(phi + delta_j)],   phi = 2 pi f x / L,   delta_j = 2 pi j / N

x is the projector column (vertical fringes) or row (horizontal fringes), L the projector width or
height, f the number of fringes across the pattern, N the number of phase-shift steps.

The single-shot image is either the paper's (the first step of the highest frequency, which carries
no fringe order) or this sensor's composite, shown as one more frame after the phase-shift set:

    I(x, y) = I_0 [1 + a cos(phi) + b sum_i cos(psi_i)],   psi_i = 2 pi (f_max x / (K_i W) + y / P_i)

the highest-frequency carrier plus code gratings, each of whose phase grows by 2 pi / K_i per carrier
fringe across the projector and which are nearly horizontal (rows of P_i projector pixels, in proportion
to the carrier's period: the same picture at any projector resolution), so their
spectral lobes sit far from the carrier's and from the albedo's. A camera pixel sees the projector row y
at almost the same place at every depth (the baseline is horizontal), so once y is known from the
calibration, psi_i tells the carrier's fringe order modulo K_i. The coarse code (K = 36 orders, more
than the working range spans) says roughly which order, the fine one (K = 6) which of the few nearby:
each decision keeps a margin of about half a radian (reconstruct.CompositeDecoder).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

SINGLE_SHOT_KINDS = ("composite", "paper")
# The composite's codes, (orders K each tells apart, row period P in projector pixels at the carrier
# period of REFERENCE_CARRIER_PERIOD_PX; scaled with the carrier's period elsewhere), fine to coarse,
# and the gratings' amplitudes (a for the carrier, b for each code; a + 2 b = 1 spans 0 .. 2 I_0). Chosen
# with python -m training.compare_codes on validation scenes (docs/single-shot.md): one code telling 36
# orders apart left a margin of 0.07 rad and its own codes named the wrong order on 25% of the pixels;
# these two leave 0.47 rad and 2.7%, for 13% more carrier phase noise; rows of 8.5/17 pixels drift too far
# with depth (a camera pixel sees another projector row) and leave 0.21 rad.
COMPOSITE_CODES = ((6, 12.0), (36, 24.0))
# The default projector's carrier period (1280 px, 100 fringes). On a projector of another resolution, or
# a set of another highest frequency, the codes' rows scale with the carrier's period, so the composite is
# the same picture, and a network trained on one projector reads another's frames once they are resampled
# to the fringe period it knows (model.DepthModel.use); rows fixed in pixels made the codes unreadable there.
REFERENCE_CARRIER_PERIOD_PX = 1280 / 100
CARRIER_AMPLITUDE, CODE_AMPLITUDE = 0.4, 0.3


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
    single_shot: str = "composite"

    def __post_init__(self):
        object.__setattr__(self, "frequencies", tuple(int(f) for f in self.frequencies))
        validate_pattern_set(self)

    @property
    def phase_shift_count(self) -> int:
        """F * N: the phase-shift images, which the multi-shot path reads."""
        return len(self.frequencies) * self.steps

    @property
    def top_frequency_frames(self) -> slice:
        """The phase-shift images of the highest frequency within a sequence."""
        return slice(self.phase_shift_count - self.steps, self.phase_shift_count)

    @property
    def top_ratio(self) -> float:
        """How many times finer the highest frequency's fringes are than the next's (5 for 1, 4, 20, 100)."""
        return self.frequencies[-1] / self.frequencies[-2]

    @property
    def count(self) -> int:
        """Frames per sequence: the phase-shift set, then the composite when there is one."""
        return self.phase_shift_count + (self.single_shot == "composite")

    @property
    def period_axis_length(self) -> int:
        """L of equation (1): the projector extent across the fringes."""
        return self.width if self.orientation == "vertical" else self.height

    @property
    def max_value(self) -> int:
        return (1 << self.bit_depth) - 1

    @property
    def single_shot_index(self) -> int:
        """Which frame the single-shot path sees (input_index of this set's single_shot)."""
        return self.input_index(self.single_shot)

    def input_index(self, kind: str) -> int:
        """Where a network reading this kind of single-shot frame finds it in a sequence: the composite
        (last), or the paper's input, the first step of the highest frequency (every set has it)."""
        if kind == "paper":
            return self.top_frequency_frames.start
        if kind != "composite" or self.single_shot != "composite":
            raise PatternError(f"a {self.single_shot!r} pattern set has no {kind!r} single-shot frame")
        return self.phase_shift_count

    @property
    def code_frequencies(self) -> list[tuple[float, float]]:
        """Each composite code grating's fringes across the pattern's fringes and along them (f_max / K, and
        the pattern's extent along them / P, P scaled with the carrier's period: REFERENCE_CARRIER_PERIOD_PX)."""
        scale = self.period_axis_length / self.frequencies[-1] / REFERENCE_CARRIER_PERIOD_PX
        along = self.height if self.orientation == "vertical" else self.width
        return [(self.frequencies[-1] / orders, along / (period * scale)) for orders, period in COMPOSITE_CODES]

    def across_along(self, xp, yp) -> tuple[np.ndarray, np.ndarray]:
        """Projector coordinates (column xp, row yp; fractional or not) as fractions of the pattern across
        its fringes and along them: the column and the row for vertical fringes, the row and the column
        for horizontal ones (a projector above or below the camera)."""
        x, y = np.asarray(xp, np.float64) / self.width, np.asarray(yp, np.float64) / self.height
        return (x, y) if self.orientation == "vertical" else (y, x)

    def shifts(self) -> np.ndarray:
        """delta_j = 2 pi j / N for j = 0 .. N-1."""
        return 2.0 * np.pi * np.arange(self.steps) / self.steps

    def names(self) -> list[str]:
        """A name for each frame in projection order."""
        names = [f"frequency {f}, step {j}" for f in self.frequencies for j in range(self.steps)]
        return names + ["single-shot composite"] * (self.single_shot == "composite")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["frequencies"] = list(self.frequencies)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> PatternSet:
        """A set written before the composite existed has no single_shot: it is the paper's."""
        try:
            return cls(**{"single_shot": "paper", **d})
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
            f"the pattern has {p.period_axis_length}"
        )
    if not p.gamma > 0:
        raise PatternError(f"gamma must be > 0, got {p.gamma}")
    if p.single_shot not in SINGLE_SHOT_KINDS:
        raise PatternError(f"single_shot must be one of {', '.join(SINGLE_SHOT_KINDS)}, got {p.single_shot!r}")


def fringe_value(p: PatternSet, frequency: int, step: int, x: np.ndarray) -> np.ndarray:
    """Pattern value at projector coordinate(s) x (may be fractional), quantized to the bit depth.

    Equation (1) with I_0 = max/2, pre-compensated by 1/gamma.
    """
    phase = 2.0 * np.pi * frequency * np.asarray(x, dtype=np.float64) / p.period_axis_length
    radiance = 0.5 * (1.0 + np.cos(phase + p.shifts()[step]))
    return np.round(p.max_value * radiance ** (1.0 / p.gamma))


def pattern_dtype(p: PatternSet):
    return np.uint8 if p.bit_depth == 8 else np.uint16


def composite_phases(p: PatternSet, xp, yp) -> list[np.ndarray]:
    """The phases of the composite's gratings at projector pixel coordinates (xp, yp), fractional
    or not (where a surface point lands, in a simulation): the carrier's first, then each code's."""
    across, along = p.across_along(xp, yp)
    return [2.0 * np.pi * (fa * across + fb * along) for fa, fb in [(p.frequencies[-1], 0.0), *p.code_frequencies]]


def composite_radiance(carrier, codes) -> np.ndarray:
    """The composite's light (0 to 1, as the projector shows it after its gamma) where its carrier and
    code gratings have these phases (composite_phases)."""
    radiance = 0.5 + 0.5 * CARRIER_AMPLITUDE * np.cos(carrier)
    for code in codes:
        radiance = radiance + 0.5 * CODE_AMPLITUDE * np.cos(code)
    return radiance


def composite_pattern(p: PatternSet) -> np.ndarray:
    """The composite single-shot pattern (module docstring), height x width, quantized like the others."""
    carrier, *codes = composite_phases(p, np.arange(p.width)[None, :], np.arange(p.height)[:, None])
    return np.round(p.max_value * composite_radiance(carrier, codes) ** (1.0 / p.gamma)).astype(pattern_dtype(p))


def pattern_images(p: PatternSet) -> list[np.ndarray]:
    """What the projector shows, in projection order: each phase-shift pattern as its profile across
    the fringes (1 x L for vertical fringes, L x 1 for horizontal; the pattern is that line repeated,
    so broadcast it to height x width to display), then the composite as a full image."""
    x = np.arange(p.period_axis_length)
    lines = [fringe_value(p, f, j, x).astype(pattern_dtype(p)) for f in p.frequencies for j in range(p.steps)]
    images = [line[None, :] if p.orientation == "vertical" else line[:, None] for line in lines]
    return images + [composite_pattern(p)] * (p.single_shot == "composite")


def generate_patterns(p: PatternSet) -> np.ndarray:
    """All patterns, shape (count, height, width), uint8 or uint16, in projection order."""
    return np.stack([np.broadcast_to(image, (p.height, p.width)) for image in pattern_images(p)])
