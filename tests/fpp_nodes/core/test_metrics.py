import numpy as np

from fpp_nodes.core.metrics import ErrorTotals, depth_errors, noise_limited_depth_std


def test_rmse_and_mre_over_valid_pixels_only():
    truth = np.array([[1000.0, 1000.0], [500.0, np.nan]])
    pred = np.array([[1003.0, 996.0], [np.nan, 1.0]])
    e = depth_errors(pred, truth, fringe_depth_mm=5.0)
    assert e.pixels == 2
    assert e.rmse_mm == np.sqrt((9 + 16) / 2)
    assert e.mre == (3 / 1000 + 4 / 1000) / 2
    assert e.coverage == 2 / 3
    assert e.order_errors == 2  # both errors exceed half of 5 mm
    first_only = depth_errors(pred, truth, truth_valid=np.array([[True, False], [False, False]]))
    assert first_only.rmse_mm == 3.0 and first_only.mre == 0.003 and first_only.coverage == 1.0


def test_totals_over_images_are_the_totals_of_their_pixels():
    truth = np.array([[1000.0, 1000.0], [500.0, np.nan]])
    a, b = np.array([[1003.0, np.nan], [500.5, 1.0]]), np.array([[np.nan, 996.0], [np.nan, np.nan]])
    totals = ErrorTotals().add(a, truth, bound=1.0).add(b, truth, bound=1.0)
    assert totals.compared == 3 and totals.reference == 6 and totals.coverage == 0.5
    assert np.isclose(totals.rmse, np.sqrt((9 + 16 + 0.25) / 3)) and totals.over == 2 and totals.share_over == 2 / 3
    assert np.isnan(ErrorTotals().rmse) and ErrorTotals().coverage == 0


def test_noise_limit_formula():
    # sigma_phi = sqrt(2/N) sigma / B; 4 steps, sigma 2, B 100 -> 0.01414 rad; 3 mm/rad -> 0.04243 mm
    assert np.isclose(noise_limited_depth_std(100.0, -3.0, 4, 2.0), 3 * 0.02 / np.sqrt(2))
