"""Phase retrieval: N-step phase shifting, temporal multi-frequency unwrapping (the paper's
equation (2)), and Fourier-transform profilometry (Takeda) with spatial unwrapping.

Phases are in radians. Wrapped phases lie in [0, 2 pi] (angle), as in the paper.
Images are modelled as I_j = A + B cos(phi + delta_j), delta_j = 2 pi j / N.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

TWO_PI = 2.0 * np.pi


class PhaseError(ValueError):
    """Images that cannot be turned into phase."""


@dataclass
class PhaseMaps:
    phase: np.ndarray  # wrapped phase phi, [0, 2 pi)
    modulation: np.ndarray  # B, in the images' units
    background: np.ndarray  # A, in the images' units


def _work_dtype(images) -> type:
    return np.float64 if images.dtype == np.float64 else np.float32


def _weighted_sum(images: np.ndarray, weights: np.ndarray, dtype) -> np.ndarray:
    """sum_j w_j I_j in one pass per pair of images (cv2 converts and accumulates without temporaries);
    integer images with weights of +-1 (every sum of 4 steps) add up exactly in integers, then convert
    once: twice as fast."""
    terms = [(np.ascontiguousarray(images[j]), float(w)) for j, w in enumerate(weights) if abs(w) > 1e-12]
    if images.dtype.kind in "ui" and all(abs(abs(w) - 1) < 1e-12 for _, w in terms):
        wide = np.int16 if images.dtype.itemsize == 1 and len(terms) <= 128 else np.int64
        (first, sign), *rest = terms
        total = first.astype(wide) if sign > 0 else np.negative(first, dtype=wide)
        for image, sign in rest:
            (np.add if sign > 0 else np.subtract)(total, image, out=total)
        return total.astype(dtype)
    depth = cv2.CV_64F if dtype == np.float64 else cv2.CV_32F
    total = None
    for k in range(0, len(terms), 2):
        (a, wa), (b, wb) = terms[k], terms[k + 1] if k + 1 < len(terms) else (terms[k][0], 0.0)
        part = cv2.addWeighted(a, wa, b, wb, 0.0, dtype=depth)
        total = part if total is None else cv2.add(total, part, dtype=depth)
    return total


def phase_sums(images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares phase's numerator and denominator, -S = -sum_j I_j sin(delta_j) and
    C = sum_j I_j cos(delta_j), of an (N, H, W) stack: phi = atan2(-S, C), B = (2/N) sqrt(S^2 + C^2)."""
    images = np.asarray(images)
    if images.ndim != 3 or images.shape[0] < 3:
        raise PhaseError(f"need a stack of N >= 3 images shaped (N, H, W), got shape {images.shape}")
    if not np.issubdtype(images.dtype, np.number) or images.dtype.kind == "c":
        raise PhaseError(f"images must be real numbers, got {images.dtype}")
    if images.dtype.kind == "f" and images.dtype != np.float64:
        images = images.astype(np.float32, copy=False)
    dtype = _work_dtype(images)
    return tuple(_weighted_sum(images, w, dtype) for w in step_weights(images.shape[0]))


def step_weights(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The weights of -S and C over N steps: -sin(delta_j) and cos(delta_j), delta_j = 2 pi j / N."""
    delta = TWO_PI * np.arange(n) / n
    return tuple(np.where(np.abs(w) < 1e-12, 0.0, w) for w in (-np.sin(delta), np.cos(delta)))  # exact zeros


def angle(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """atan2(y, x) in [0, 2 pi]. float32 (camera images) goes through cv2.phase: within 2e-4 rad of
    atan2 (about 3e-4 mm of depth in the default rig), 0.25 ms a 640x480 map where numpy's atan2 takes
    12 ms on a CPU without AVX-512; float64 gets numpy's exact atan2, in [0, 2 pi)."""
    if y.dtype == np.float32:
        return cv2.phase(x, y)
    phi = np.arctan2(y, x)
    np.add(phi, TWO_PI, out=phi, where=phi < 0)
    return phi


def wrap_phase(phase):
    """A phase, or a difference of phases, brought into [-pi, pi)."""
    return (phase + np.pi) % TWO_PI - np.pi


def wrapped_phase(images: np.ndarray) -> np.ndarray:
    """Least-squares wrapped phase of N phase-shifted images."""
    return angle(*phase_sums(images))


def phase_and_modulation(images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Wrapped phase and modulation B = (2/N) sqrt(S^2 + C^2) of N phase-shifted images."""
    y, x = phase_sums(images)
    if y.dtype == np.float32:  # both in one pass, the angle exactly cv2.phase's
        modulation, phase = cv2.cartToPolar(x, y)
    else:
        modulation, phase = cv2.magnitude(y, x), angle(y, x)
    modulation *= 2.0 / images.shape[0]
    return phase, modulation


def phase_shift(images: np.ndarray) -> PhaseMaps:
    """Wrapped phase, modulation B and background A = mean(I)."""
    images = np.asarray(images)
    phase, modulation = phase_and_modulation(images)
    return PhaseMaps(phase, modulation, images.mean(axis=0, dtype=_work_dtype(images)))


NOISE_WINDOW = 5  # pixels: one pixel's N-step residual has N - 3 degrees of freedom (1 at N = 4)


def phase_noise(images: np.ndarray, modulation: np.ndarray, window: int = NOISE_WINDOW) -> np.ndarray:
    """The standard deviation of the least-squares phase (rad) that the images' own noise causes,
    sqrt(2/N) sigma / B, per pixel (inf where B is 0). sigma^2 is the residual of the N-step fit over
    its N - 3 degrees of freedom: the images' power at the harmonics the fit leaves out (DFT bins 2 to
    N - 2; at N = 4 the alternating sum I0 - I1 + I2 - I3), pooled over window x window pixels and, for
    integer images, at least the camera's rounding (1/12 count^2). Needs N >= 4: three steps fit
    exactly and leave no residual."""
    n = images.shape[0]
    dtype = _work_dtype(images)
    power = None
    for basis, weight in zip(*residual_bases(n)):
        part = _weighted_sum(images, basis, dtype)
        part = cv2.multiply(part, part, scale=weight)
        power = part if power is None else cv2.add(power, part)
    return pooled_phase_noise(power, modulation, n, images.dtype.kind in "ui", window)


def residual_bases(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The residual power of an N-step fit as sum_k weight_k (basis_k . I)^2, scaled so that it is
    sigma_phi^2 B^2 per pixel: (bases (K, N), weights (K,)). The bases are the DFT bins 2 to N - 2
    (bins k and N - k carry the same power, except k = N / 2)."""
    if n < 4:
        raise PhaseError(f"the phase noise needs N >= 4 phase-shift steps (3 fit exactly), got {n}")
    delta = TWO_PI * np.arange(n) / n
    scale = 2.0 / (n * (n - 3))  # 2/N for the phase, over N - 3 degrees of freedom
    bases, weights = [], []
    for k in range(2, n // 2 + 1):
        for basis in (np.cos(k * delta), np.sin(k * delta)):
            if np.abs(basis).max() > 1e-9:
                bases.append(basis)
                weights.append((1.0 if 2 * k == n else 2.0) / n * scale)
    return np.array(bases), np.array(weights)


def pooled_phase_noise(
    power: np.ndarray, modulation: np.ndarray, n: int, integer: bool, window: int = NOISE_WINDOW
) -> np.ndarray:
    """phase_noise from each pixel's residual power (residual_bases): pooled over window x window
    pixels, at least the rounding of integer images, over B."""
    power = cv2.boxFilter(power, -1, (window, window), borderType=cv2.BORDER_REPLICATE)
    if integer:
        np.maximum(power, 2.0 / n / 12.0, out=power)  # 2/N sigma^2, sigma^2 the rounding's 1/12 count^2
    with np.errstate(divide="ignore"):
        return cv2.sqrt(power) / modulation


def blur_variance(
    phase: np.ndarray, modulation: np.ndarray, coarser_modulation: np.ndarray, ratio: float, where, step: int = 8
) -> float:
    """The variance (px^2) of the blur a sequence shows, from two of its frequencies: a Gaussian blur
    of variance s keeps exp(-s k^2 / 2) of the contrast of fringes whose phase changes by k rad a
    pixel, so fringes ratio times finer than the coarser ones keep exp(-s k^2 (1 - 1 / ratio^2) / 2)
    of their modulation against them (k = |grad phase| of the finer, central differences). The median
    over the pixels where, on every step-th pixel of every step-th row, at least 0. It holds the
    projector's defocus as well as the camera's: an upper bound of the camera's blur, which is what
    defocus_phase_bias needs."""
    rows, cols = slice(1, phase.shape[0] - 1, step), slice(1, phase.shape[1] - 1, step)
    gy = (phase[2::step, cols].astype(np.float64) - phase[:-2:step, cols]) / 2
    gx = (phase[rows, 2::step].astype(np.float64) - phase[rows, :-2:step]) / 2
    k2 = (gx * gx + gy * gy) * (1.0 - 1.0 / ratio**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -2.0 * np.log(modulation[rows, cols] / coarser_modulation[rows, cols]) / k2
    s = s[where[rows, cols] & np.isfinite(s)]
    return max(0.0, float(np.median(s))) if s.size else 0.0


def defocus_phase_bias(phase: np.ndarray, modulation: np.ndarray, variance: float) -> np.ndarray:
    """How far (rad) the camera's blur moves each pixel's phase where the albedo changes across the
    fringes. A blur of variance s mixes a pixel's neighbours into it, each by its own brightness: to
    first order in s, the phase moves by s grad(phase) . grad(ln B) towards the brighter side (B: a
    frequency's modulation, which follows the blurred albedo; docs/multi-shot.md). A plain surface
    has none; a striped or printed one under a blur of 1 px moves by up to a few tenths of a radian.
    Central differences, the border replicated; d ln B as (B+ - B-) / (B+ + B-), which it is to
    first order (no logarithm; NaN where both are 0)."""
    p = np.pad(np.asarray(phase, np.float64), 1, mode="edge")
    b = np.pad(np.asarray(modulation, np.float64), 1, mode="edge")
    with np.errstate(divide="ignore", invalid="ignore"):
        bx = (b[1:-1, 2:] - b[1:-1, :-2]) / (b[1:-1, 2:] + b[1:-1, :-2])
        by = (b[2:, 1:-1] - b[:-2, 1:-1]) / (b[2:, 1:-1] + b[:-2, 1:-1])
    px, py = (p[1:-1, 2:] - p[1:-1, :-2]) / 2, (p[2:, 1:-1] - p[:-2, 1:-1]) / 2
    return np.abs(variance * (px * bx + py * by))


def unwrap_temporal(wrapped: list[np.ndarray], frequencies, max_residual: float = np.pi / 2):
    """Hierarchical temporal unwrapping, equation (2):

        phi_i = phi_i^w + 2 pi INT((phi_{i-1} f_i / f_{i-1} - phi_i^w) / 2 pi)

    starting from the first frequency, whose wrapped phase is absolute (f_1 = 1).
    Returns the unwrapped phase of the highest frequency and a mask of pixels whose fringe order is
    consistent at every level: |phi_{i-1} f_i / f_{i-1} - phi_i| <= max_residual. A larger residual
    means the lower frequency's phase was too noisy (or the pixel mixes two surfaces) to pick the order.
    """
    if len(wrapped) != len(frequencies):
        raise PhaseError(f"{len(wrapped)} wrapped phase maps for {len(frequencies)} frequencies")
    if frequencies[0] != 1:
        raise PhaseError(f"temporal unwrapping starts from one fringe, got first frequency {frequencies[0]}")
    phase, worst = wrapped[0], None
    for f_prev, f, phase_w in zip(frequencies, frequencies[1:], wrapped[1:]):
        # (phi_{i-1} f_i/f_{i-1} - phi_i^w) / 2 pi: the order, and the residual, in cycles
        cycles = cv2.addWeighted(phase, f / f_prev / TWO_PI, phase_w, -1.0 / TWO_PI, 0.0)
        order = np.rint(cycles)
        residual = cv2.absdiff(cycles, order)
        worst = residual if worst is None else cv2.max(worst, residual)
        phase = cv2.scaleAdd(order, TWO_PI, phase_w)
    if worst is None:
        return phase, np.ones(phase.shape, bool)
    return phase, worst <= np.float32(max_residual / TWO_PI)


def unwrap_spatial(wrapped: np.ndarray) -> np.ndarray:
    """Least-squares spatial unwrapping (Ghiglia and Romero 1994, DCT solution of the Poisson equation),
    made congruent with the wrapped phase: the result differs from it by whole multiples of 2 pi.

    Correct where the true phase changes by less than pi between neighbouring pixels; height
    discontinuities and shadows break it, as they break every spatial unwrapper.
    """
    h, w = np.shape(wrapped)
    # cv2.dct wants even sizes: an odd side repeats its last row or column, whose differences are then
    # 0 and consistent with the rest (a zero-padded Poisson right-hand side is not: it was up to 2 pi off)
    psi = np.pad(np.asarray(wrapped, np.float64), ((0, h % 2), (0, w % 2)), mode="edge")
    ph, pw = psi.shape

    dx = np.zeros_like(psi)
    dy = np.zeros_like(psi)
    dx[:, :-1] = wrap_phase(np.diff(psi, axis=1))
    dy[:-1, :] = wrap_phase(np.diff(psi, axis=0))
    rho = dx.copy()
    rho[:, 1:] -= dx[:, :-1]
    rho += dy
    rho[1:, :] -= dy[:-1, :]
    rho_hat = cv2.dct(rho)
    ii = np.arange(ph)[:, None]
    jj = np.arange(pw)[None, :]
    denom = 2.0 * np.cos(np.pi * ii / ph) + 2.0 * np.cos(np.pi * jj / pw) - 4.0
    denom[0, 0] = 1.0
    phi_hat = rho_hat / denom
    phi_hat[0, 0] = 0.0
    psi, smooth = psi[:h, :w], cv2.idct(phi_hat)[:h, :w]
    return psi + TWO_PI * np.rint((smooth - psi) / TWO_PI)


def ftp_wrapped_phase(
    image: np.ndarray, vertical_fringes: bool = True, band: float = 0.5, carrier: float | None = None
):
    """Takeda's Fourier-transform profilometry on one fringe image.

    Keeps the spectral lobe around the positive carrier (found as the strongest peak away from DC
    near the axis across the fringes), with a Hann window of half-width band * carrier, and returns
    (wrapped phase in [0, 2 pi), lobe amplitude). The phase grows along +x (or +y), so it equals the
    projector phase where the projector phase grows along +x too. carrier (cycles per image width),
    where known from the calibration, replaces the search (texture can outshine the fringes).
    """
    img = np.asarray(image, np.float64)
    if img.ndim != 2 or min(img.shape) < 8:
        raise PhaseError(f"FTP needs one 2-D image of at least 8x8 pixels, got shape {img.shape}")
    if not vertical_fringes:
        phase, amp = ftp_wrapped_phase(img.T, True, band, carrier)
        return phase.T, amp.T
    h, w = img.shape
    spectrum = np.fft.fft2(img - img.mean())
    fx = np.fft.fftfreq(w) * w  # cycles per image width
    fy = np.fft.fftfreq(h) * h
    row_power = np.abs(spectrum[np.abs(fy) <= h / 16]).sum(axis=0)  # near the fx axis: not the composite's code
    search = fx >= 2.0
    if not search.any():
        raise PhaseError("image too narrow to find a fringe carrier")
    if carrier is None:
        carrier = fx[search][np.argmax(row_power[search])]
    half = max(band * abs(carrier), 1.0)  # a carrier falling along +x (a mirrored projector): its negative lobe
    wx = np.where(np.abs(fx - carrier) < half, 0.5 * (1 + np.cos(np.pi * (fx - carrier) / half)), 0.0)
    wy = np.where(np.abs(fy) < half, 0.5 * (1 + np.cos(np.pi * fy / half)), 0.0)
    analytic = np.fft.ifft2(spectrum * wy[:, None] * wx[None, :])
    return np.mod(np.angle(analytic), TWO_PI), 2.0 * np.abs(analytic)


def code_lobe_centres(image: np.ndarray, count: int, rising) -> list[tuple[float, float]]:
    """Where the composite's count code gratings sit in an image's spectrum (cycles per image width and
    height): the count strongest lobes nearer square to the carrier's fringes than along them (the codes'
    rows run nearly along the carrier's fringes; rising: the carrier phase's gradient, per pixel along a
    row and down a column), past the albedo's within 4 cycles of zero; finest rows (most cycles across
    the carrier's gradient) first, as patterns.COMPOSITE_CODES. A camera rolled about its axis rolls
    every lobe: by direction they are told apart up to about 30 degrees (the fine code's lobe lies 12
    degrees off the carrier's fringes), and a camera mounted turned a quarter (portrait) is read as it
    is. Each lobe is one of a mirrored pair, whose phases are opposite: the finest code's is the one
    whose phase rises along the carrier's, the others' those whose rows run as its do, so a projector
    showing its image mirrored (rear or ceiling mode) is read as it is."""
    img = np.asarray(image, np.float64)
    h, w = img.shape
    power = np.abs(np.fft.fft2(img - img.mean()))
    fx = (np.fft.fftfreq(w) * w)[None, :]
    fy = (np.fft.fftfreq(h) * h)[:, None]
    gx, gy = np.asarray(rising, np.float64) / np.hypot(*rising)

    def along(fx, fy, direction=(gx, gy)):  # a lobe's frequency (cycles per image) along a direction, per pixel
        return fx / w * direction[0] + fy / h * direction[1]

    def across(fx, fy):  # ... and square to the carrier's gradient
        return along(fx, fy, (-gy, gx))

    power[(np.hypot(fx, fy) < 4.0) | (np.abs(across(fx, fy)) <= np.abs(along(fx, fy)))] = 0
    lobes = []
    for _ in range(count):
        row, col = np.unravel_index(np.argmax(power), power.shape)
        lobes.append((float(fx[0, col]), float(fy[row, 0])))
        for sign in (1, -1):  # the lobe and its mirror
            power[np.hypot(fx - sign * lobes[-1][0], fy - sign * lobes[-1][1]) < 0.25 * np.hypot(*lobes[-1])] = 0
    lobes.sort(key=lambda c: -abs(across(*c)))

    def towards(lobe, direction):  # the lobe of the pair whose phase rises along direction (per pixel)
        return lobe if along(*lobe, direction) > 0 else (-lobe[0], -lobe[1])

    finest = towards(lobes[0], rising)
    return [finest] + [towards(lobe, (finest[0] / w, finest[1] / h)) for lobe in lobes[1:]]


def ftp_code_phases(image: np.ndarray, centres: list[tuple[float, float]]) -> list[np.ndarray]:
    """The composite's code gratings by FTP: each spectral lobe at its centre (cycles per image width
    and height, from code_lobe_centres or the calibration), kept with a Hann window that reaches
    halfway to the nearest other lobe or to DC (the albedo's). Returns each wrapped phase in
    [0, 2 pi). Exact on smooth surfaces (a plane: about 0.003 rad), which is what the calibration needs."""
    img = np.asarray(image, np.float64)
    if img.ndim != 2 or min(img.shape) < 16:
        raise PhaseError(f"FTP needs one 2-D image of at least 16x16 pixels, got shape {img.shape}")
    h, w = img.shape
    spectrum = np.fft.fft2(img - img.mean())
    fx = (np.fft.fftfreq(w) * w)[None, :]
    fy = (np.fft.fftfreq(h) * h)[:, None]
    phases = []
    for cx, cy in centres:
        radius = 0.5 * min(np.hypot(cx - ox, cy - oy) for ox, oy in [(0.0, 0.0), *centres] if (ox, oy) != (cx, cy))
        r = np.hypot(fx - cx, fy - cy)
        window = np.where(r < radius, 0.5 * (1 + np.cos(np.pi * r / radius)), 0.0)
        phases.append(np.mod(np.angle(np.fft.ifft2(spectrum * window)), TWO_PI))
    return phases
