import numpy as np

from fpp_nodes.core.metrics import depth_errors, mre, noise_limited_depth_std, rmse


def test_rmse_and_mre_over_valid_pixels_only():
    truth = np.array([[1000.0, 1000.0], [500.0, np.nan]])
    pred = np.array([[1003.0, 996.0], [np.nan, 1.0]])
    e = depth_errors(pred, truth, fringe_depth_mm=5.0)
    assert e.pixels == 2
    assert e.rmse_mm == np.sqrt((9 + 16) / 2)
    assert e.mre == (3 / 1000 + 4 / 1000) / 2
    assert e.coverage == 2 / 3
    assert e.order_errors == 2  # both errors exceed half of 5 mm
    mask = np.array([[True, False], [False, False]])
    assert rmse(pred, truth, mask) == 3.0 and mre(pred, truth, mask) == 0.003


def test_noise_limit_formula():
    # sigma_phi = sqrt(2/N) sigma / B; 4 steps, sigma 2, B 100 -> 0.01414 rad; 3 mm/rad -> 0.04243 mm
    assert np.isclose(noise_limited_depth_std(100.0, -3.0, 4, 2.0), 3 * 0.02 / np.sqrt(2))
