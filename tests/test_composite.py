"""The composite single-shot pattern: its calibration and its decoding, against the simulator's geometry."""
from dataclasses import replace

import numpy as np
import pytest

from fpp_nodes.core.calibration import Calibration, CalibrationError
from fpp_nodes.core.model import CompositeDecoder, ModelError
from fpp_nodes.core.patterns import CODE_ORDERS
from fpp_nodes.core.simulation import (FAMILY_NAMES, SURFACE_DEPTH_MM, SceneRenderer, make_scene, plane_scene,
                                       random_rig)


def exact_phases(renderer, patterns):
    """Carrier and code phase of every pixel, from where its surface point lands in the projector."""
    xp, yp = renderer.xp[renderer.crop], renderer.yp[renderer.crop]
    fx, fy = patterns.code_frequencies
    carrier = 2 * np.pi * patterns.frequencies[-1] * xp / patterns.width
    code = 2 * np.pi * (fx * xp / patterns.width + fy * yp / patterns.height)
    return carrier, code


def as_network_output(carrier, code):
    return np.stack([np.sin(carrier), np.cos(carrier), np.sin(code), np.cos(code)]).astype(np.float32)


def test_the_code_model_tells_the_row_phase_across_the_working_range(rig, patterns, calibration, pixel_grid):
    """Fitted from noisy planes at 1100-1300 mm, it holds from 1000 to 1350 mm within 0.01 rad, a tenth
    of the code's margin (pi / CODE_ORDERS = 0.098 rad); measured 0.002 rad."""
    u, v = pixel_grid((rig.height, rig.width))
    fy = patterns.code_frequencies[1]
    for z in (SURFACE_DEPTH_MM[0], 1175.0, SURFACE_DEPTH_MM[1]):
        renderer = SceneRenderer(rig, plane_scene(rig, z))
        truth = 2 * np.pi * fy * renderer.yp[renderer.crop] / patterns.height
        error = np.angle(np.exp(1j * (calibration.code_row_phase_at_depth(z, u, v) - truth)))
        assert np.abs(error).max() < 0.01, z


@pytest.mark.parametrize("family", FAMILY_NAMES)
def test_exact_phases_decode_to_the_exact_depth_on_every_family(rig, patterns, calibration, family):
    """Given the true phases, the code picks the right order at every lit pixel with full confidence:
    what is left is the calibration's error (< 0.05 mm), never an order (9-17 mm)."""
    decoder = CompositeDecoder(calibration, SURFACE_DEPTH_MM)
    scene_rig = random_rig(np.random.default_rng(3), rig)
    scene = make_scene(scene_rig, family, 3)
    renderer = SceneRenderer(scene_rig, scene)
    lit = renderer.lit[renderer.crop]
    depth, confidence = decoder(as_network_output(*exact_phases(renderer, patterns)), 0.5)
    assert np.abs(depth - scene.depth_mm)[lit].max() < 0.05
    assert confidence[lit].min() > 0.9


def test_a_code_half_way_between_two_orders_is_nan_not_a_guess(rig, patterns, calibration):
    """Half-way, neither order is trusted at 0.6: the next order's code sits 2 pi / K away, give or take
    how far the row phase moves in one order (up to 0.05 rad in the corners: half of pi / K)."""
    decoder = CompositeDecoder(calibration, SURFACE_DEPTH_MM)
    renderer = SceneRenderer(rig, plane_scene(rig, 1150.0))
    carrier, code = exact_phases(renderer, patterns)
    depth, confidence = decoder(as_network_output(carrier, code + np.pi / CODE_ORDERS), 0.6)
    assert np.all(confidence < 0.6) and np.isnan(depth).all()
    depth, confidence = decoder(as_network_output(carrier, code + 0.3 * np.pi / CODE_ORDERS), 0.5)
    assert np.all(confidence > 0.65) and np.abs(depth - 1150.0).max() < 0.05


def test_a_working_range_wider_than_the_code_is_refused(calibration):
    with pytest.raises(ModelError, match="fringe orders"):
        CompositeDecoder(calibration, (900.0, 1500.0))
    paper = Calibration(calibration.camera, calibration.model, replace(calibration.patterns, single_shot="paper"),
                        calibration.reference_depth_mm)
    with pytest.raises(ModelError, match="code model"):
        CompositeDecoder(paper, SURFACE_DEPTH_MM)


def test_a_calibration_has_a_code_model_exactly_with_the_composite(calibration):
    d = calibration.to_dict()
    assert Calibration.from_dict(d).code_model is not None
    del d["code_model"]
    with pytest.raises(CalibrationError, match="code model"):
        Calibration.from_dict(d)
    del d["patterns"]["single_shot"]  # a file written before the composite: the paper's 16 frames
    old = Calibration.from_dict(d)
    assert old.patterns.single_shot == "paper" and old.patterns.count == 16
