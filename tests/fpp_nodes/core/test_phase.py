import numpy as np
import pytest

from fpp_nodes.core.phase import (
    PhaseError,
    ftp_wrapped_phase,
    phase_noise,
    phase_shift,
    unwrap_spatial,
    unwrap_temporal,
    wrapped_phase,
)

TWO_PI = 2 * np.pi


def fringes(phi, a, b, n):
    return np.stack([a + b * np.cos(phi + TWO_PI * j / n) for j in range(n)])


def angle_error(a, b):
    return np.abs(np.angle(np.exp(1j * (a - b))))


@pytest.mark.parametrize("n", [3, 4, 5, 8])
def test_noise_free_wrapped_phase_is_exact(n):
    rng = np.random.default_rng(n)
    phi = rng.uniform(0, TWO_PI, (40, 50))
    a, b = rng.uniform(50, 100, phi.shape), rng.uniform(5, 50, phi.shape)
    maps = phase_shift(fringes(phi, a, b, n))
    assert angle_error(maps.phase, phi).max() < 1e-6
    assert maps.phase.min() >= 0 and maps.phase.max() < TWO_PI
    np.testing.assert_allclose(maps.modulation, b, rtol=1e-9)
    np.testing.assert_allclose(maps.background, a, rtol=1e-9)


def test_eight_bit_images_give_float32_phase_within_rounding():
    phi = np.linspace(0, TWO_PI, 640, endpoint=False)[None, :].repeat(4, 0)
    imgs = np.rint(fringes(phi, 120.0, 100.0, 4)).astype(np.uint8)
    est = wrapped_phase(imgs)
    assert est.dtype == np.float32
    # rounding to integers moves the phase by at most about sqrt(2)*0.5/100 rad
    assert angle_error(est, phi).max() < 0.008


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("n", [4, 6])
def test_integer_images_decode_as_their_values_do(dtype, n):
    """Integer images (at N = 4 summed in integers, else by cv2), also as rows of a larger stack, give
    the phase and modulation their values give in float64."""
    rng = np.random.default_rng(n)
    phi = rng.uniform(0, TWO_PI, (60, 80))
    top = np.iinfo(dtype).max
    images = np.rint(fringes(phi, 0.5 * top, 0.45 * top, n)).astype(dtype)
    exact = phase_shift(images.astype(np.float64))
    for stack in (images, images[:, 10:50]):  # the second: rows of each image, not one block of memory
        got = phase_shift(stack)
        rows = slice(0, 60) if stack is images else slice(10, 50)
        assert angle_error(got.phase, exact.phase[rows]).max() < 2e-4  # cv2's angle
        np.testing.assert_allclose(got.modulation, exact.modulation[rows], rtol=1e-6)


@pytest.mark.parametrize("n", [4, 6])
def test_phase_noise_is_what_the_images_noise_makes(n):
    """sqrt(2/N) sigma / B, estimated from the images alone, and it is the phase error they really have."""
    rng = np.random.default_rng(n)
    phi = rng.uniform(0, TWO_PI, (200, 200))
    sigma, b = 2.0, 30.0
    images = fringes(phi, 100.0, b, n) + rng.normal(0, sigma, (n,) + phi.shape)
    maps = phase_shift(images)
    noise = phase_noise(images, maps.modulation)
    expected = np.sqrt(2.0 / n) * sigma / b
    assert np.median(noise) == pytest.approx(expected, rel=0.1)
    assert np.sqrt(np.mean(angle_error(maps.phase, phi) ** 2)) == pytest.approx(expected, rel=0.1)


def test_phase_noise_needs_a_residual():
    with pytest.raises(PhaseError, match="N >= 4"):
        phase_noise(np.zeros((3, 8, 8)), np.ones((8, 8)))


def test_temporal_unwrapping_recovers_absolute_phase_and_flags_bad_orders():
    freqs = (1, 4, 20, 100)
    x = np.linspace(0.02, 0.98, 5000)[None, :]  # one fringe wraps at the projector edges
    rng = np.random.default_rng(0)
    wrapped = [np.mod(TWO_PI * f * x + rng.normal(0, 0.02, x.shape), TWO_PI) for f in freqs]
    phase, ok = unwrap_temporal(wrapped, freqs)
    assert ok.all()
    assert np.abs(phase - TWO_PI * 100 * x).max() < 0.1
    # corrupt the 20-fringe phase by half a fringe at a few pixels: they must be flagged
    bad = wrapped[2].copy()
    bad[0, ::500] = np.mod(bad[0, ::500] + np.pi, TWO_PI)
    _, ok = unwrap_temporal(wrapped[:2] + [bad] + wrapped[3:], freqs)
    assert not ok[0, ::500].any() and ok.sum() == ok.size - 10


def test_temporal_unwrapping_needs_one_fringe_first():
    with pytest.raises(PhaseError, match="one fringe"):
        unwrap_temporal([np.zeros((2, 2))] * 2, (4, 20))


@pytest.mark.parametrize("shape", [(120, 160), (120, 161), (121, 160), (121, 161)])
@pytest.mark.parametrize("slope", [0.15, 1.5])
def test_spatial_unwrapping_of_a_smooth_phase_is_exact_up_to_a_constant(shape, slope):
    """Of any size: on odd sides the DCT's even padding once left parts of a phase changing by 1 rad a
    pixel (a code grating 4 px a period, as a 320x240 camera sees it) 2 pi off."""
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]]
    true = slope * v + 0.3 * u + 0.002 * (v - 60) ** 2 + 3 * np.sin(u / 30.0)
    got = unwrap_spatial(np.mod(true, TWO_PI))
    offset = got - true
    assert np.abs(offset - offset[0, 0]).max() < 1e-9
    assert abs(offset[0, 0] / TWO_PI - round(offset[0, 0] / TWO_PI)) < 1e-9


def test_ftp_recovers_a_tilted_carrier():
    v, u = np.mgrid[0:128, 0:256]
    phi = TWO_PI * 20 * u / 256 + 0.5 * np.sin(v / 20.0)
    img = 100 + 80 * np.cos(phi)
    est, amp = ftp_wrapped_phase(img)
    inner = (slice(10, -10), slice(10, -10))
    assert angle_error(est, phi)[inner].max() < 0.02
    assert np.abs(amp[inner] - 80).max() < 4


def test_bad_stacks_are_refused():
    with pytest.raises(PhaseError, match="N >= 3"):
        wrapped_phase(np.zeros((2, 4, 4)))
    with pytest.raises(PhaseError, match="real numbers"):
        wrapped_phase(np.zeros((4, 4, 4), complex))


def test_the_compiled_angle_is_atan2_in_zero_to_two_pi():
    """fused._angle, the polynomial atan2 the multi-shot pass vectorizes: within 1e-6 rad of numpy's
    (float32 rounding near 2 pi is 2.4e-7), on every octant, the axes and the origin (0, as atan2)."""
    from fpp_nodes.core.fused import _angle

    grid = np.concatenate([np.linspace(-300, 300, 601), [-1e-3, 1e-3, 0.0]]).astype(np.float32)
    for x in grid[::7]:
        for y in grid:
            expected = np.arctan2(np.float64(y), np.float64(x)) % TWO_PI
            got = _angle(y, x)
            assert 0 <= got <= np.float32(TWO_PI)
            assert abs(angle_error(got, expected)) < 1e-6, (y, x, got, expected)
    assert _angle(np.float32(0), np.float32(0)) == 0


NOWHERE_TO_CACHE = """
import numpy as np
from fpp_nodes.core.calibration import Calibration, default_calibration_path
from fpp_nodes.core.reconstruct import PspReconstructor
from fpp_nodes.core.scenes import plane_scene
from fpp_nodes.core.simulation import Rig, render

rig = Rig()
images = render(rig, plane_scene(rig, 1200.0), rig.pattern_set(), np.random.default_rng(0)).images
depth = PspReconstructor(Calibration.load(default_calibration_path()))(images).depth_mm
print(np.isfinite(depth).mean(), np.nanmedian(np.abs(depth - 1200.0)))
"""


def test_with_nowhere_to_cache_the_compiled_passes_the_paths_still_run_and_say_so():
    """A read-only install run by a user with no writable home leaves numba no place for its cache, and
    numba then refuses to compile cache=True functions at all: every depth node and fpp failed at
    import. numba's own setting NUMBA_CACHE_LOCATOR_CLASSES, with only the locator for zip archives,
    leaves it none just so: the module warns, naming NUMBA_CACHE_DIR, and the multi-shot path still
    measures a plane at 1200 mm (95% of it, median within 0.05 mm)."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_LOCATOR_CLASSES": "ZipCacheLocator"}
    r = subprocess.run([sys.executable, "-c", NOWHERE_TO_CACHE], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "NUMBA_CACHE_DIR" in r.stderr
    given, error = map(float, r.stdout.split())
    assert given > 0.95 and error < 0.05
