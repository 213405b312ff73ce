"""The phase-aware single-shot decoding (core/model.py): network outputs -> depth, and the confidence
that says NaN rather than guess."""

import numpy as np
import pytest

from fpp_nodes.core.model import PhaseOrderDecoder, order_confidence


def ideal_outputs(rig, patterns, calibration, depth_mm, sigma_orders, amplitude=0.3):
    """What a perfect network says about a scene at depth_mm: exact fringe numerator/denominator, r off
    by 0.3 of its own sigma, log sigma."""
    u, v = rig.camera().ideal_pixels()
    phase = calibration.model.phase_at_depth(depth_mm, u, v) * np.ones((rig.height, rig.width))
    reference = calibration.model.phase_at_depth(calibration.reference_depth_mm, u, v)
    orders = (phase - reference) / (2 * np.pi) + 0.3 * sigma_orders
    return np.stack(
        [amplitude * np.sin(phase), amplitude * np.cos(phase), orders, np.full(phase.shape, np.log(sigma_orders))]
    ).astype(np.float32)


@pytest.mark.parametrize("depth_mm", [1080.0, 1200.0, 1310.0])
def test_exact_phase_and_a_coarse_order_give_the_calibrated_depth(rig, patterns, calibration, depth_mm):
    decoder = PhaseOrderDecoder(calibration)
    depth, confidence = decoder(ideal_outputs(rig, patterns, calibration, depth_mm, 0.1), 0.99)
    assert np.all(confidence > 0.99)
    # float32 phase of ~440 rad carries 3e-5 rad of rounding: 6e-5 mm of depth
    np.testing.assert_allclose(depth, depth_mm, atol=1e-3)


def test_an_unsure_order_is_nan_never_a_guess(rig, patterns, calibration):
    decoder = PhaseOrderDecoder(calibration)
    depth, confidence = decoder(ideal_outputs(rig, patterns, calibration, 1200.0, 2.0), 0.9)
    assert np.isnan(depth).all() and np.all(confidence < 0.3)


def test_order_confidence_is_the_gaussian_probability_of_the_right_order():
    sigma = np.array([0.05, 0.2, 0.5, 1.0, 5.0], np.float32)
    # P(|N(0, sigma)| < 0.5) = erf(0.5 / (sqrt(2) sigma)), from math.erf
    from math import erf, sqrt

    expected = [erf(0.5 / (sqrt(2) * s)) for s in sigma]
    np.testing.assert_allclose(order_confidence(np.log(sigma)), expected, atol=1e-6)
