import numpy as np
import pytest

from fpp_nodes.core.patterns import PatternError, PatternSet, generate_patterns


def test_equation_1_values_and_order():
    p = PatternSet(frequencies=(1, 4), steps=4, width=64, height=8, gamma=1.0, single_shot="paper")
    pats = generate_patterns(p)
    assert pats.shape == (8, 8, 64) and pats.dtype == np.uint8
    x = np.arange(64)
    for i, (f, j) in enumerate((f, j) for f in p.frequencies for j in range(p.steps)):
        expected = np.round(255 * 0.5 * (1 + np.cos(2 * np.pi * f * x / 64 + 2 * np.pi * j / 4)))
        np.testing.assert_array_equal(pats[i, 3], expected)
        assert np.all(pats[i] == pats[i, 0])  # vertical fringes: every row is the same


def test_horizontal_16_bit_any_resolution_and_steps():
    p = PatternSet(
        frequencies=(1, 3, 9),
        steps=5,
        width=37,
        height=50,
        orientation="horizontal",
        bit_depth=16,
        gamma=1.0,
        single_shot="paper",
    )
    pats = generate_patterns(p)
    assert pats.shape == (15, 50, 37) and pats.dtype == np.uint16
    assert np.all(pats[7] == pats[7][:, :1])  # horizontal fringes: constant along a row
    assert pats.max() == 65535


def test_gamma_precompensation_makes_the_light_sinusoidal():
    p = PatternSet(frequencies=(1,), steps=4, width=1000, height=2, bit_depth=16, gamma=2.2)
    light = (generate_patterns(p)[0, 0] / 65535.0) ** 2.2
    expected = 0.5 * (1 + np.cos(2 * np.pi * np.arange(1000) / 1000))
    assert np.abs(light - expected).max() < 1e-3


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(steps=2), "steps must be >= 3"),
        (dict(frequencies=(1, 20, 4)), "strictly increasing"),
        (dict(frequencies=(4, 20)), "first frequency must be 1"),
        (dict(frequencies=(1, 700)), "projector pixels"),
        (dict(orientation="diagonal"), "orientation"),
        (dict(bit_depth=12), "bit_depth"),
        (dict(gamma=0.0), "gamma"),
    ],
)
def test_invalid_pattern_sets_are_refused_with_the_reason(kwargs, message):
    with pytest.raises(PatternError, match=message):
        PatternSet(**kwargs)


def test_composite_rides_along_as_the_last_frame():
    p = PatternSet(gamma=2.2)
    pats = generate_patterns(p)
    assert p.count == p.phase_shift_count + 1 == len(p.names()) == pats.shape[0] == 17
    assert p.single_shot_index == 16 and PatternSet(single_shot="paper").single_shot_index == 12
    light = (pats[16] / 255.0) ** 2.2
    (fx, fy), (gx, gy) = p.code_frequencies
    x, y = np.arange(p.width)[None, :] / p.width, np.arange(p.height)[:, None] / p.height
    expected = 0.5 + 0.2 * np.cos(2 * np.pi * 100 * x)
    expected = expected + 0.15 * (np.cos(2 * np.pi * (fx * x + fy * y)) + np.cos(2 * np.pi * (gx * x + gy * y)))
    assert np.abs(light - expected).max() < 0.01  # within 8-bit quantization after gamma
    # the codes' phases move 2 pi / 6 and 2 pi / 36 per carrier fringe, in rows of 12 and 24 pixels
    assert fx * 6 == 100 and fy == 800 / 12 and gx * 36 == 100 and gy == 800 / 24


def test_a_set_written_before_the_composite_is_the_papers():
    d = PatternSet().to_dict()
    del d["single_shot"]
    assert PatternSet.from_dict(d).single_shot == "paper"
    with pytest.raises(PatternError, match="single_shot"):
        PatternSet(single_shot="gray")


def test_the_composite_is_the_same_picture_at_any_projector_resolution():
    """The codes' rows scale with the carrier's period (REFERENCE_CARRIER_PERIOD_PX): at twice the
    default's resolution the composite is the default's at twice the size, and on a 1920 x 1080
    projector its rows are 1.5 times the default's pixels, as its carrier's period is."""
    default, double, full_hd = PatternSet(), PatternSet(width=2560, height=1600), PatternSet(width=1920, height=1080)
    assert double.code_frequencies == default.code_frequencies
    for (fx, fy), (gx, gy) in zip(full_hd.code_frequencies, default.code_frequencies):
        assert fx == gx and full_hd.height / fy == pytest.approx(1.5 * default.height / gy)


def test_the_horizontal_composite_is_the_vertical_one_turned():
    """For a projector above or below the camera: the composite with horizontal fringes on a 1280 x 800
    projector is, pixel for pixel, the vertical one of an 800 x 1280 projector transposed (its carrier
    across the rows, its codes' rows along them, the same period: 8 px)."""
    horizontal, vertical = PatternSet(orientation="horizontal"), PatternSet(width=800, height=1280)
    assert np.array_equal(generate_patterns(horizontal)[-1], generate_patterns(vertical)[-1].T)
    assert horizontal.code_frequencies == vertical.code_frequencies
