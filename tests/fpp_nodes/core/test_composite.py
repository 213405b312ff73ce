"""The composite single-shot pattern: its calibration and its decoding, against the simulator's geometry."""

from dataclasses import replace

import numpy as np
import pytest

from fpp_nodes.core.calibration import Calibration, CalibrationError
from fpp_nodes.core.patterns import CODE_ORDERS
from fpp_nodes.core.phase import PhaseError
from fpp_nodes.core.reconstruct import CompositeDecoder, order_surfaces
from fpp_nodes.core.scenes import FAMILY_NAMES, SURFACE_DEPTH_MM, make_scene, plane_scene
from fpp_nodes.core.simulation import SceneRenderer, random_rig


def exact_phases(renderer, patterns):
    """Carrier and code phase of every pixel, from where its surface point lands in the projector."""
    xp, yp = renderer.xp[renderer.crop], renderer.yp[renderer.crop]
    fx, fy = patterns.code_frequencies
    carrier = 2 * np.pi * patterns.frequencies[-1] * xp / patterns.width
    code = 2 * np.pi * (fx * xp / patterns.width + fy * yp / patterns.height)
    return carrier, code


def as_network_output(carrier, code):
    return np.stack([np.sin(carrier), np.cos(carrier), np.sin(code), np.cos(code)]).astype(np.float32)


def test_the_code_model_tells_the_row_phase_across_the_working_range(rig, patterns, calibration):
    """Fitted from noisy planes at 1100-1300 mm, it holds from 1000 to 1350 mm within 0.01 rad, a seventh
    of the code's margin (half the 0.137 rad between the closest two orders); measured 0.002 rad."""
    u, v = rig.camera().ideal_pixels()
    fy = patterns.code_frequencies[1]
    for z in (SURFACE_DEPTH_MM[0], 1175.0, SURFACE_DEPTH_MM[1]):
        renderer = SceneRenderer(rig, plane_scene(rig, z))
        truth = 2 * np.pi * fy * renderer.yp[renderer.crop] / patterns.height
        error = np.angle(np.exp(1j * (calibration.code_row_phase_at_depth(z, u, v) - truth)))
        assert np.abs(error).max() < 0.01, z


@pytest.mark.parametrize("family", FAMILY_NAMES)
def test_exact_phases_decode_to_the_exact_depth_on_every_family(rig, patterns, calibration, family):
    """Given the true phases, the code picks the right order at every lit pixel: what is left is the
    calibration's error (< 0.05 mm), never an order (9-17 mm); only pixels at a step (whose
    neighbourhood is mostly the other surface) say NaN."""
    decoder = CompositeDecoder(calibration, SURFACE_DEPTH_MM)
    scene_rig = random_rig(np.random.default_rng(3), rig)
    scene = make_scene(scene_rig, family, 3)
    renderer = SceneRenderer(scene_rig, scene)
    lit = renderer.lit[renderer.crop]
    depth, confidence = decoder(as_network_output(*exact_phases(renderer, patterns)), 0.5, lit)
    given = np.isfinite(depth)
    assert not (given & ~lit).any() and np.abs(depth - scene.depth_mm)[given].max() < 0.05
    assert given.sum() > 0.97 * lit.sum() and np.median(confidence[lit]) > 0.99


def test_a_surface_outvotes_scattered_order_errors_and_a_code_of_noise_is_nan(rig, patterns, calibration):
    """A fifth of the pixels' codes point at a wrong order (1-5 orders off): the neighbourhood outvotes
    every one (NaN) and keeps the rest. A code that carries nothing (uniform noise) gets no vote: NaN,
    never a guess."""
    decoder = CompositeDecoder(calibration, SURFACE_DEPTH_MM)
    renderer = SceneRenderer(rig, plane_scene(rig, 1150.0))
    carrier, code = exact_phases(renderer, patterns)
    rng = np.random.default_rng(0)
    wrong = rng.random(code.shape) < 0.2
    noisy = code + wrong * rng.integers(1, 6, code.shape) * 2 * np.pi / CODE_ORDERS
    depth, confidence = decoder(as_network_output(carrier, noisy), 0.5)
    assert not np.isfinite(depth[wrong]).any() and np.isfinite(depth[~wrong]).mean() > 0.99
    assert np.nanmax(np.abs(depth - 1150.0)) < 0.05
    depth, confidence = decoder(as_network_output(carrier, rng.uniform(0, 2 * np.pi, code.shape)), 0.5)
    assert np.isnan(depth).mean() > 0.99


def test_a_coherent_patch_of_wrong_orders_is_its_own_surface_and_too_small_to_trust(rig, patterns, calibration):
    """A 40 x 40 patch whose codes all point one order up (what texture at the code's scale does):
    inside it every pixel agrees with its neighbours, so the window's vote alone keeps it, an order
    (9-17 mm) off. Its absolute phase steps by 2 pi at its border, so it is a surface of its own, and
    1600 pixels are fewer than min_surface_px: NaN, while the plane around it keeps its depth."""
    renderer = SceneRenderer(rig, plane_scene(rig, 1150.0))
    carrier, code = exact_phases(renderer, patterns)
    patch = np.zeros(code.shape, bool)
    patch[200:240, 300:340] = True
    biased = as_network_output(carrier, code + patch * 2 * np.pi / CODE_ORDERS)
    depth, _ = CompositeDecoder(calibration, SURFACE_DEPTH_MM)(biased, 0.5)
    assert np.mean(np.abs(depth[patch] - 1150.0) > 5) > 0.5  # the window's vote alone: an order off
    depth, confidence = CompositeDecoder(calibration, SURFACE_DEPTH_MM, min_surface_px=2000)(biased, 0.5)
    assert not np.isfinite(depth[patch]).any() and np.mean(confidence[patch] == 0) > 0.9
    assert np.isfinite(depth[~patch]).mean() > 0.99 and np.nanmax(np.abs(depth - 1150.0)) < 0.05


def test_order_surfaces_join_neighbours_whose_absolute_phases_differ_by_less_than_pi():
    """A ramp of absolute phase (1 rad per pixel): one surface. Two orders added to a block: the block
    is a surface of its own, and the pixels either side of its border are on none."""
    absolute = np.tile(np.arange(64, dtype=np.float32), (48, 1))
    fringes = np.ones(absolute.shape, bool)
    labels, sizes = order_surfaces(absolute, fringes)
    assert sizes.size == 2 and sizes[1] == absolute.size
    stepped = absolute.copy()
    stepped[10:30, 20:40] += 4 * np.pi
    labels, sizes = order_surfaces(stepped, fringes)
    assert labels[20, 30] != labels[5, 5] and labels[20, 30] > 0 and labels[5, 5] > 0
    assert labels[20, 19] == labels[20, 20] == 0 and labels[9, 30] == labels[10, 30] == 0
    assert sizes[labels[20, 30]] == 18 * 18


def test_the_code_tells_every_two_orders_of_the_working_range_apart(calibration):
    """The design numbers (CODE_ORDERS, CODE_ROW_PERIOD_PX): on the default rig the codes of any two
    orders in 1000-1350 mm stay at least 0.12 rad apart (measured 0.137), and the row phase's drift
    over the decoder's window is a straight line within 2e-3 rad (measured 5e-4)."""
    decoder = CompositeDecoder(calibration, SURFACE_DEPTH_MM)
    assert decoder.min_separation > 0.12 and decoder.row_fit_error < 2e-3


def test_a_working_range_wider_than_the_code_is_refused(calibration):
    with pytest.raises(PhaseError, match="fringe orders"):
        CompositeDecoder(calibration, (900.0, 1500.0))
    paper = Calibration(
        calibration.camera,
        calibration.model,
        replace(calibration.patterns, single_shot="paper"),
        calibration.reference_depth_mm,
    )
    with pytest.raises(PhaseError, match="code model"):
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
