"""The multi-shot path on the default noisy rig, calibrated from noisy planes, over held-out scenes."""
import numpy as np
import pytest

from fpp_nodes.core.metrics import depth_errors
from fpp_nodes.core.reconstruct import PspReconstructor, reconstruct_ftp
from fpp_nodes.core.simulation import plane_scene, render
from fpp_nodes.core.workflow import fringe_depth_mm, held_out_scenes, score


@pytest.fixture(scope="module")
def results(rig, patterns, calibration):
    psp = PspReconstructor(calibration)
    rows = []
    for name, scene, seed in held_out_scenes(rig, 4):
        capture = render(rig, scene, patterns, np.random.default_rng(seed))
        multi = psp(capture.images)
        single = reconstruct_ftp(capture.images[-patterns.steps], calibration)
        ftp = depth_errors(single.depth_mm, capture.depth_mm, capture.valid, fringe_depth_mm(calibration, multi.phase))
        rows.append((score(multi, capture.depth_mm, capture.valid, calibration, rig.noise_sigma, name), ftp, capture))
    return rows


def test_multi_shot_is_within_twice_the_noise_limit(results):
    for r, _, _ in results:
        assert r.errors.rmse_mm <= 2.0 * r.noise_limited_rmse_mm, r
        assert r.errors.rmse_mm < 0.06


def test_no_fringe_order_errors_and_shadows_are_all_that_is_lost(results, calibration):
    tallest_step = max(np.abs(np.diff(c.depth_mm, axis=1)).max() for _, _, c in results)
    u, v = np.arange(640.0)[None, :], np.arange(480.0)[:, None]
    one_fringe = fringe_depth_mm(calibration, calibration.model.phase_at_depth(1200.0, u, v)).max()
    assert 10 < one_fringe < 16
    assert tallest_step > 2 * one_fringe  # the scenes do test temporal unwrapping
    for r, _, capture in results:
        assert r.errors.order_errors == 0, r
        assert r.errors.coverage > 0.98, r  # of the lit pixels; the rest sit on edges (flying-pixel filter)


def test_no_wrong_depth_is_reported_in_shadows(results, rig, patterns, calibration):
    psp = PspReconstructor(calibration)
    for _, _, capture in results:
        depth = psp(capture.images).depth_mm
        wrong = np.isfinite(depth) & (np.abs(depth - capture.depth_mm) > 1.0)
        assert wrong.sum() <= 2e-4 * wrong.size  # a few mixed pixels at shadow terminators


def test_noise_limit_is_what_the_formula_says_on_a_plane(rig, patterns, calibration):
    """On a plane the measured scatter about the truth must match the formula, not just be below 2x."""
    capture = render(rig, plane_scene(rig, 1200.0), patterns, np.random.default_rng(11))
    r = score(PspReconstructor(calibration)(capture.images), capture.depth_mm, capture.valid, calibration,
              rig.noise_sigma, "plane")
    assert r.noise_limited_rmse_mm * 0.9 < r.errors.rmse_mm < r.noise_limited_rmse_mm * 1.3, r


def test_ftp_baseline_is_reported_and_fails_where_it_must(results, rig, patterns, calibration):
    # on a plane at the reference depth FTP is fine ...
    capture = render(rig, plane_scene(rig, calibration.reference_depth_mm), patterns, np.random.default_rng(3))
    plane = reconstruct_ftp(capture.images[-patterns.steps], calibration)
    assert depth_errors(plane.depth_mm, capture.depth_mm, capture.valid).rmse_mm < 0.2
    # ... on scenes with steps taller than a fringe, spatial unwrapping loses the order
    for r, ftp, _ in results:
        assert ftp.order_errors > 0 and ftp.rmse_mm > 10 * r.errors.rmse_mm
