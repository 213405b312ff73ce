"""The multi-shot path's per-pixel work in two compiled passes (numba): sequence_phase reads each image
once, row by row, keeping every intermediate in row buffers that stay in the CPU's first-level cache;
trusted_points turns the phase into depth, noise, the trusted pixels and XYZ. Separate numpy or OpenCV
calls each pass over the whole 640x480 frame, about a hundred passes for a 16-image sequence. The
science is phase.py's and reconstruct.py's, which tests compare these passes against. The single-shot
decoding's per-pixel chains likewise (code_phase and those after it; its neighbourhood sums and
medians stay OpenCV's).

The passes hold no Python objects and release the interpreter lock (nogil), so row bands run on
threads of their own (reconstruct.PspReconstructor): no threading layer of numba's, nothing that a
fork (training.dataset's workers) or a second calling thread could upset. Compiled once per image
dtype and cached in NUMBA_CACHE_DIR where it is set, else next to this file, else in ~/.cache/numba.
"""

from __future__ import annotations

import math
import warnings

import numba
import numpy as np


def _cache_found() -> bool:
    """Whether numba finds a writable place to cache this module's passes. A read-only install run by a
    user with no writable home (a container's or a service's user) has none, and numba would then refuse
    to compile them at all: they are compiled at each start instead, with a warning."""
    try:
        numba.njit(cache=True)(_cache_found)
        return True
    except RuntimeError:  # numba's "cannot cache function ...: no locator available for file ..."
        warnings.warn(
            f"numba finds no writable place to cache the compiled passes of {__file__} (beside it, "
            "NUMBA_CACHE_DIR or the user's cache directory): they are compiled again at each start "
            "(seconds); set NUMBA_CACHE_DIR to a writable directory to keep them",
            stacklevel=2,
        )
        return False


_CACHE = _cache_found()

_HALF_PI, _PI, _TWO_PI = np.float32(math.pi / 2), np.float32(math.pi), np.float32(2 * math.pi)
_INV_TWO_PI = np.float32(1 / (2 * math.pi))
# atan(t) ~ t P(t^2) on [0, 1], within 2.5e-7 rad: a weighted least-squares fit toward the minimax
# polynomial (cv2.phase is within 2e-4 rad). Written out so that the compiler vectorizes it; libm's
# atan2 is one pixel at a time.
_A0, _A1, _A2, _A3 = (np.float32(a) for a in (0.99999611, -0.33317368, 0.19807816, -0.13233342))
_A4, _A5, _A6 = (np.float32(a) for a in (0.07962367, -0.03360422, 0.00681179))
_FAST = {"contract", "arcp", "nsz"}  # fused multiply-adds; not "nnan": a NaN image stays NaN


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _angle(y, x):
    """atan2(y, x) in [0, 2 pi]."""
    ax, ay = abs(x), abs(y)
    hi, lo = max(ax, ay), min(ax, ay)
    t = lo / (hi + np.float32(1e-30))  # 0 at the origin, as atan2
    s = t * t
    a = t * (_A0 + s * (_A1 + s * (_A2 + s * (_A3 + s * (_A4 + s * (_A5 + s * _A6))))))
    a = _HALF_PI - a if ay > ax else a
    a = _PI - a if x < 0 else a
    return _TWO_PI - a if y < 0 else a


# Per-pixel updates are written as sums and unconditional stores: a conditional store (a running
# maximum) kept the compiler from vectorizing the loop, 3x slower.
@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def sequence_phase(
    images, first, last, sin_weights, cos_weights, ratios, residual_bases, residual_weights, max_cycles, full_scale
):
    """From (F*N [+ more], H, W) phase-shift images in projection order, F >= 2 frequencies of N steps,
    at rows first to last: the top frequency's unwrapped phase, its modulation B, the pixels whose
    fringe order agrees at every level (|cycles - order| <= max_cycles) and whose top-frequency images
    stay below full_scale, the top frequency's residual power (sum over residual_bases of weight x
    (basis . I)^2), and the next lower frequency's B. ratios are f_i / f_(i-1). float32 throughout."""
    n, levels, width = sin_weights.shape[0], ratios.shape[0] + 1, images.shape[2]
    phase = np.empty((last - first, width), np.float32)
    modulation = np.empty((last - first, width), np.float32)
    coarser = np.empty((last - first, width), np.float32)
    trusted = np.empty((last - first, width), np.bool_)
    power = np.empty((last - first, width), np.float32)
    y, x = np.empty(width, np.float32), np.empty(width, np.float32)
    fails = np.empty(width, np.float32)
    top = (levels - 1) * n
    for i in range(last - first):
        r = first + i
        fails[:] = 0
        unwrapped = phase[i]
        for level in range(levels):
            y[:] = 0
            x[:] = 0
            for j in range(n):
                image, ws, wc = images[level * n + j, r], np.float32(sin_weights[j]), np.float32(cos_weights[j])
                for c in range(width):
                    value = np.float32(image[c])
                    y[c] += ws * value
                    x[c] += wc * value
            if level == 0:
                for c in range(width):
                    unwrapped[c] = _angle(y[c], x[c])
            else:  # equation (2): the order from the level below, scaled to this frequency
                scale = np.float32(ratios[level - 1]) * _INV_TWO_PI
                for c in range(width):
                    wrapped = _angle(y[c], x[c])
                    cycles = unwrapped[c] * scale - wrapped * _INV_TWO_PI
                    order = np.float32(np.rint(cycles))
                    fails[c] += np.float32(abs(cycles - order) > max_cycles)
                    unwrapped[c] = wrapped + _TWO_PI * order
            if level >= levels - 2:  # B of the top frequency, and of the one below it (the blur reads both)
                b = modulation[i] if level == levels - 1 else coarser[i]
                for c in range(width):
                    b[c] = np.float32(2.0 / n) * math.sqrt(x[c] * x[c] + y[c] * y[c])
        for j in range(n):
            image = images[top + j, r]
            for c in range(width):
                fails[c] += np.float32(np.float32(image[c]) >= full_scale)
        keep = trusted[i]
        for c in range(width):
            keep[c] = fails[c] == 0
        p = power[i]
        p[:] = 0
        for k in range(residual_bases.shape[0]):
            x[:] = 0
            for j in range(n):
                image, w = images[top + j, r], np.float32(residual_bases[k, j])
                for c in range(width):
                    x[c] += w * np.float32(image[c])
            w = np.float32(residual_weights[k])
            for c in range(width):
                p[c] += w * x[c] * x[c]
    return phase, modulation, trusted, power, coarser


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def trusted_points(
    phase, phase_noise, coarser, trusted, lo, first, last, terms, slope, rays_x, rays_y, blur, limits, out
):
    """A band of rows, from image row lo on: its unwrapped phase, phase noise (rad), a lower frequency's
    modulation and trusted pixels -> the rational model's depth (ca + cb phi) / (da + db phi), depth
    noise |dz/dphi| phase_noise and defocus bias |dz/dphi| phase.defocus_phase_bias(phase, coarser,
    blur), dz/dphi = (cb da - ca db) / (da + db phi)^2, under reconstruct.trusted_depth's rules: a
    pixel is kept where it is trusted, its depth noise is at most limits[0] mm, so are its
    4-neighbours' (defocus carries fringes across a shadow edge), no kept 4-neighbour's depth is more
    than limits[1] mm away (a flying pixel), and its own defocus bias is at most limits[2] mm.
    Writes image rows first to last of out = (depth, depth noise, kept, XYZ along the rays), NaN
    where not kept. terms (4, H, W), slope |cb da - ca db| and the rays are the whole image's."""
    height, width = phase.shape
    max_noise, max_step, max_bias = np.float32(limits[0]), np.float32(limits[1]), np.float32(limits[2])
    depth, noise = np.empty((height, width), np.float32), np.empty((height, width), np.float32)
    bias, biased = np.empty(width, np.float32), np.empty((height, width), np.bool_)
    for r in range(height):
        _defocus_bias_row(phase, coarser, r, np.float32(blur), bias)
        ca, cb, da, db, s = terms[0, lo + r], terms[1, lo + r], terms[2, lo + r], terms[3, lo + r], slope[lo + r]
        phi_row, sigma_row, trusted_row = phase[r], phase_noise[r], trusted[r]
        for c in range(width):
            phi = phi_row[c]
            den = db[c] * phi + da[c]
            z = (cb[c] * phi + ca[c]) / den
            dz = s[c] / (den * den)
            sigma = sigma_row[c] * dz
            keep = trusted_row[c] & (sigma <= max_noise)
            noise[r, c] = sigma
            depth[r, c] = z if keep else np.nan
            biased[r, c] = not bias[c] * dz <= max_bias  # NaN: not known, so biased
    eroded = np.empty((height, width), np.float32)
    for r in range(height):  # beyond the band and the image counts as kept, as cv2.erode's border
        _neighbour_rule(depth[max(r - 1, 0)], depth[r], depth[min(r + 1, height - 1)], np.inf, eroded[r])
    depth_out, noise_out, kept_out, xyz_out = out
    for r in range(first - lo, last - lo):
        z_row = depth_out[lo + r]
        _neighbour_rule(eroded[max(r - 1, 0)], eroded[r], eroded[min(r + 1, height - 1)], max_step, z_row)
        kept, noise_row, x, y, xyz = (
            kept_out[lo + r],
            noise_out[lo + r],
            rays_x[lo + r],
            rays_y[lo + r],
            xyz_out[lo + r],
        )
        for c in range(width):  # a biased pixel's neighbours keep their depth: its bias is its own
            z, sigma = z_row[c], noise[r, c]
            z = np.float32(np.nan) if biased[r, c] else z
            z_row[c] = z
            finite = np.isfinite(z)
            kept[c] = finite
            noise_row[c] = sigma if finite else np.nan
            xyz[c, 0] = x[c] * z
            xyz[c, 1] = y[c] * z
            xyz[c, 2] = z


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _bias_at(phase, b, r, up, down, c, left, right, blur):
    """phase.defocus_phase_bias at one pixel, its neighbours' indices given (the border replicated)."""
    gx = np.float32(0.5) * (phase[r, right] - phase[r, left])
    gy = np.float32(0.5) * (phase[down, c] - phase[up, c])
    lx = (b[r, right] - b[r, left]) / (b[r, right] + b[r, left])
    ly = (b[down, c] - b[up, c]) / (b[down, c] + b[up, c])
    return blur * abs(gx * lx + gy * ly)


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _defocus_bias_row(phase, b, r, blur, out):
    """phase.defocus_phase_bias along row r of a band (its first and last rows replicated: halo rows,
    but at the image's top and bottom, where the image's border is)."""
    height, width = phase.shape
    up, down = max(r - 1, 0), min(r + 1, height - 1)
    for c in range(1, width - 1):
        out[c] = _bias_at(phase, b, r, up, down, c, c - 1, c + 1, blur)
    out[0] = _bias_at(phase, b, r, up, down, 0, 0, min(1, width - 1), blur)
    out[width - 1] = _bias_at(phase, b, r, up, down, width - 1, max(width - 2, 0), width - 1, blur)


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _jump(z, a, b, c, d, step):
    """Some of z's 4 neighbours a to d is more than step away. Comparisons with NaN are false, so a
    NaN neighbour is no step."""
    return (abs(z - a) > step) | (abs(z - b) > step) | (abs(z - c) > step) | (abs(z - d) > step)


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _kept(z, a, b, c, d, max_step):
    """z where its 4 neighbours a to d are all finite (max_step inf: the erosion) or none that is
    finite is more than max_step away (the flying pixels); NaN otherwise."""
    if max_step == np.inf:
        return z if np.isfinite(a + b + c + d) else np.nan
    return np.nan if _jump(z, a, b, c, d, max_step) else z


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _neighbour_rule(up, row, down, max_step, out):
    """_kept along a row (operands loaded before the choice, so that the loop vectorizes); a missing
    neighbour at the sides is the pixel itself."""
    width = row.shape[0]
    out[0] = _kept(row[0], up[0], down[0], row[0], row[min(1, width - 1)], max_step)
    for c in range(1, width - 1):
        out[c] = _kept(row[c], up[c], down[c], row[c - 1], row[c + 1], max_step)
    out[width - 1] = _kept(
        row[width - 1], up[width - 1], down[width - 1], row[max(width - 2, 0)], row[width - 1], max_step
    )


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def code_phase(carrier, codes, intercepts, rates, spacings, lowest, low, high, max_miss, turns):
    """reconstruct.CompositeDecoder.code_phase, row by row: codes, intercepts, rates and spacings are
    (K, H, W), coarse code first; lowest, low and high the decoder's maps; max_miss (rad) the most a
    candidate's codes may miss by, together; turns, how many of the coarse code's turns from the lowest
    candidate a pixel's candidates may lie in. Every turn's candidate is refined for every pixel and the
    choice is a select, so that each loop vectorizes (a candidate outside the working range or missing
    by more counts as missing by inf; where all do, NaN). float32 throughout."""
    height, width = carrier.shape
    count = codes.shape[0]
    own = np.empty((height, width), np.float32)
    left = np.empty((count, width), np.float32)
    base, first, last = np.empty(width, np.float32), np.empty(width, np.float32), np.empty(width, np.float32)
    fits, turn, here = np.empty(width, np.float32), np.empty(width, np.float32), np.empty(width, np.float32)
    miss, best, least = np.empty(width, np.float32), np.empty(width, np.float32), np.empty(width, np.float32)
    most = np.float32(max_miss * max_miss)
    for r in range(height):
        for c in range(width):
            phase = carrier[r, c]
            b = phase + _TWO_PI * np.float32(np.ceil((lowest[r, c] - phase) * _INV_TWO_PI))  # lowest candidate
            base[c] = b
            first[c] = np.ceil((low[r, c] - b) * _INV_TWO_PI)
            last[c] = np.floor((high[r, c] - b) * _INV_TWO_PI)
        for k in range(count):  # what j s_k must match
            for c in range(width):
                left[k, c] = codes[k, r, c] - intercepts[k, r, c] - rates[k, r, c] * base[c]
        coarse, spacing = left[0], spacings[0, r]
        for c in range(width):  # where the coarse code fits in its first turn (from j = 0, either way it runs)
            turn[c] = _TWO_PI / np.abs(spacing[c])
            j = (coarse[c] - _TWO_PI * np.floor(coarse[c] * _INV_TWO_PI)) / spacing[c]
            fits[c] = j + turn[c] if j < 0 else j
            least[c] = np.inf
        for t in range(turns):
            for c in range(width):
                here[c] = fits[c] + np.float32(t) * turn[c]
            _refine(here, left, spacings, r)
            miss[:] = 0
            for k in range(count):
                code, spacing = left[k], spacings[k, r]
                for c in range(width):
                    miss[c] += _wrapped_square(code[c] - here[c] * spacing[c])
            for c in range(width):
                j, m = here[c], miss[c]
                better = (j >= first[c]) & (j <= last[c]) & (m <= most) & (m < least[c])
                least[c] = m if better else least[c]
                best[c] = j if better else best[c]
        out = own[r]
        for c in range(width):
            out[c] = base[c] + _TWO_PI * best[c] if least[c] < np.inf else np.float32(np.nan)
    return own


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def outside_phase(where, carrier, codes, intercepts, rates, spacings, lowest, turn, low, high, turns, max_miss):
    """reconstruct.CompositeDecoder.outside_phase at the flat indices where of the maps: carrier, lowest,
    turn (the coarse code's turn in carrier phase), low and high flat (H W,); codes, intercepts, rates
    and spacings (K, H W), coarse code first; turns, whole turns from lowest. In each turn's window the
    one order the coarse code fits in its first turn from the window's start, moved by each finer code
    as code_phase does and rounded; of those outside [low, high] that all codes fit within max_miss
    (root sum of squares), the one they fit best. NaN where none. The pixels are gathered first and
    are the inmost loop, so that each loop vectorizes."""
    count, n = codes.shape[0], where.shape[0]
    phase, first, step = np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32)
    lo, hi = np.empty(n, np.float32), np.empty(n, np.float32)
    code, a, b = np.empty((count, n), np.float32), np.empty((count, n), np.float32), np.empty((count, n), np.float32)
    s = np.empty((count, n), np.float32)
    for c in range(n):
        i = where[c]
        phase[c], first[c], step[c], lo[c], hi[c] = carrier[i], lowest[i], turn[i], low[i], high[i]
        for k in range(count):
            code[k, c], a[k, c], b[k, c], s[k, c] = codes[k, i], intercepts[k, i], rates[k, i], spacings[k, i]
    best = np.full(n, np.nan, np.float32)
    least = np.full(n, np.float32(max_miss * max_miss), np.float32)
    left = np.empty((count, n), np.float32)
    base, j = np.empty(n, np.float32), np.empty(n, np.float32)
    for t in turns:
        for c in range(n):
            start = first[c] + np.float32(t) * step[c]
            base[c] = phase[c] + _TWO_PI * np.float32(np.ceil((start - phase[c]) * _INV_TWO_PI))  # the window's lowest
        for k in range(count):
            for c in range(n):
                left[k, c] = code[k, c] - a[k, c] - b[k, c] * base[c]
        for c in range(n):
            j[c] = (left[0, c] - _TWO_PI * np.floor(left[0, c] * _INV_TWO_PI)) / s[0, c]
        for k in range(1, count):
            for c in range(n):
                miss = left[k, c] - j[c] * s[k, c]
                j[c] += (miss - _TWO_PI * np.float32(np.rint(miss * _INV_TWO_PI))) / s[k, c]
        for c in range(n):
            order = np.float32(np.rint(j[c]))
            miss = np.float32(0)
            for k in range(count):
                miss += _wrapped_square(left[k, c] - order * s[k, c])
            candidate = base[c] + _TWO_PI * order
            outside = (candidate < lo[c]) | (candidate > hi[c])
            if outside & (miss <= least[c]):
                least[c], best[c] = miss, candidate
    return best


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _refine(j, left, spacings, r):
    """j (a row) moved by each finer code to the nearest value it fits exactly, then rounded."""
    for k in range(1, left.shape[0]):
        for c in range(j.shape[0]):
            miss = left[k, c] - j[c] * spacings[k, r, c]
            j[c] += (miss - _TWO_PI * np.float32(np.rint(miss * _INV_TWO_PI))) / spacings[k, r, c]
    for c in range(j.shape[0]):
        j[c] = np.rint(j[c])


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _wrapped_square(miss):
    """The square of a phase difference brought into [-pi, pi)."""
    miss -= _TWO_PI * np.float32(np.floor((miss + _PI) * _INV_TWO_PI))
    return miss * miss


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def demodulated_blocks(image, phasors, factor):
    """Block sums (factor x factor pixels) of an image (float32) demodulated, for
    reconstruct.code_sidebands. phasors (2 P, H, W): P phasors' sines and cosines (any amplitude), the
    carrier's first; the demodulations are by the carrier's conjugate unit phasor e = conj(u_0), then
    by e u_k and e conj(u_k) for each other k. Returns (3 P - 2, 2, H / factor, W / factor): the real
    and imaginary parts' sums of image x each demodulation, then of each u_k itself (k > 0). Rows are
    summed at full width first, across each block once per block."""
    count, width = phasors.shape[0] // 2, image.shape[1]
    rows, cols = image.shape[0] // factor, width // factor
    planes = 3 * count - 2
    sums = np.empty((planes, 2, rows, cols), np.float32)
    rows_sum = np.empty((planes, 2, width), np.float32)
    re, im = np.empty((count, width), np.float32), np.empty((count, width), np.float32)
    tiny = np.float32(1e-12)
    # One accumulator a loop: the compiler cannot tell rows of rows_sum apart, so a loop storing to
    # several ran scalar, twice as slow.
    for block in range(rows):
        rows_sum[:] = 0
        for r in range(block * factor, (block + 1) * factor):
            for k in range(count):  # unit phasors
                sines, cosines, re_k, im_k = phasors[2 * k, r], phasors[2 * k + 1, r], re[k], im[k]
                for c in range(width):
                    scale = np.float32(1) / np.sqrt(sines[c] * sines[c] + cosines[c] * cosines[c] + tiny)
                    re_k[c] = cosines[c] * scale
                    im_k[c] = sines[c] * scale
            value, re_0, im_0 = image[r], re[0], im[0]
            total = rows_sum[0, 0]  # e = conj(u_0)
            for c in range(width):
                total[c] += value[c] * re_0[c]
            total = rows_sum[0, 1]
            for c in range(width):
                total[c] -= value[c] * im_0[c]
            for k in range(1, count):
                re_k, im_k = re[k], im[k]
                total = rows_sum[2 * k - 1, 0]  # e u_k: carrier - code
                for c in range(width):
                    total[c] += value[c] * (re_0[c] * re_k[c] + im_0[c] * im_k[c])
                total = rows_sum[2 * k - 1, 1]
                for c in range(width):
                    total[c] += value[c] * (re_0[c] * im_k[c] - im_0[c] * re_k[c])
                total = rows_sum[2 * k, 0]  # e conj(u_k): carrier + code
                for c in range(width):
                    total[c] += value[c] * (re_0[c] * re_k[c] - im_0[c] * im_k[c])
                total = rows_sum[2 * k, 1]
                for c in range(width):
                    total[c] -= value[c] * (im_0[c] * re_k[c] + re_0[c] * im_k[c])
                total = rows_sum[2 * count - 2 + k, 0]  # u_k itself
                for c in range(width):
                    total[c] += re_k[c]
                total = rows_sum[2 * count - 2 + k, 1]
                for c in range(width):
                    total[c] += im_k[c]
        for d in range(planes):
            for j in range(2):
                row, out = rows_sum[d, j], sums[d, j, block]
                for b in range(cols):
                    total = np.float32(0)
                    for i in range(factor):
                        total += row[b * factor + i]
                    out[b] = total
    return sums


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def sideband_ratio(sums, area):
    """reconstruct.code_sidebands' ratio from demodulated_blocks' sums, windowed, as (rows, cols,
    planes x 2): per block, the larger over the codes of (|plus - carrier u| + |minus - carrier
    conj(u)|) / 2 / |carrier|, u the code's mean phasor (its sum / area). One pass, no complex temporaries."""
    rows, cols, codes = sums.shape[0], sums.shape[1], (sums.shape[2] // 2 - 1) // 3
    ratio = np.empty((rows, cols), np.float32)
    inverse_area = np.float32(1) / np.float32(area)
    for r in range(rows):
        for c in range(cols):
            s = sums[r, c]
            cr, ci = s[0], s[1]
            largest = np.float32(0)
            for k in range(codes):
                pr, pi, mr, mi = s[2 + 4 * k], s[3 + 4 * k], s[4 + 4 * k], s[5 + 4 * k]
                ur, ui = s[2 + 4 * codes + 2 * k] * inverse_area, s[3 + 4 * codes + 2 * k] * inverse_area
                # carrier u and carrier conj(u)
                plus = _length(pr - (cr * ur - ci * ui), pi - (cr * ui + ci * ur))
                minus = _length(mr - (cr * ur + ci * ui), mi - (ci * ur - cr * ui))
                largest = max(largest, np.float32(0.5) * (plus + minus))
            ratio[r, c] = largest / max(_length(cr, ci), np.float32(1e-6))
    return ratio


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _length(x, y):
    """|x + i y| (a square root vectorizes, libm's hypot does not)."""
    return np.sqrt(x * x + y * y)


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def nearest_order(carrier, steps, base, step):
    """carrier + 2 pi k nearest the phase that median_16's steps stand for (base + steps x step), per
    pixel: the order a neighbourhood's median phase names."""
    out = np.empty(carrier.shape, np.float32)
    base, step = np.float32(base), np.float32(step)
    for r in range(carrier.shape[0]):
        for c in range(carrier.shape[1]):
            phase = carrier[r, c]
            median = base + np.float32(steps[r, c]) * step
            out[r, c] = phase + _TWO_PI * np.float32(np.rint((median - phase) * _INV_TWO_PI))
    return out


# Pixels a side of reconstruct.CompositeDecoder's blocks (why: there); the two passes below are written for it
BLOCK = 2


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def block_phasors(out, fringes):
    """reconstruct.CompositeDecoder's blocks: per block of BLOCK x BLOCK pixels (a last, partial one where
    H or W is odd), the sums of out's planes (P, H, W) over its pixels that show fringes, and whether any
    does."""
    planes, height, width = out.shape
    whole = width // 2
    sums = np.zeros((planes, -(-height // 2), -(-width // 2)), np.float32)
    shown = np.zeros(sums.shape[1:], np.bool_)
    weight = np.empty(width, np.float32)
    for r in range(height):
        lit = fringes[r]
        for c in range(width):
            weight[c] = np.float32(1) if lit[c] else np.float32(0)
        for p in range(planes):
            row, row_sums = out[p, r], sums[p, r // 2]
            for b in range(whole):
                row_sums[b] += row[2 * b] * weight[2 * b] + row[2 * b + 1] * weight[2 * b + 1]
            if width % 2:
                row_sums[whole] += row[width - 1] * weight[width - 1]
        row_shown = shown[r // 2]
        for b in range(whole):
            row_shown[b] |= lit[2 * b] | lit[2 * b + 1]
        if width % 2:
            row_shown[whole] |= lit[width - 1]
    return sums, shown


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def block_depth(out, absolute, confidence, fringes, code_planes, intercepts, rates, ca, cb, da, db):
    """reconstruct.CompositeDecoder's last step, per pixel: its carrier phase (the angle of out's first
    two planes) at the order nearest its block's absolute phase (NaN where the block has none), through
    the rational model (depth = (ca + cb phi) / (da + db phi)), and its block's confidence; both NaN where
    the pixel shows no fringes. Also that absolute phase (phi), and how far the pixel's own codes (out's
    planes code_planes and the one after each, in the order of intercepts and rates) miss the code
    phases it predicts (intercept + rate phi): the sum of the squares of each code's (wrapped) miss."""
    height, width = fringes.shape
    depth = np.empty((height, width), np.float32)
    sure = np.empty((height, width), np.float32)
    taken = np.empty((height, width), np.float32)
    missed = np.empty((height, width), np.float32)
    nan = np.float32(np.nan)
    block_phase, block_confidence = np.empty(width, np.float32), np.empty(width, np.float32)
    for r in range(height):
        for c in range(width):  # the row's blocks, pixel by pixel: the loops below then vectorize
            block_phase[c], block_confidence[c] = absolute[r // 2, c // 2], confidence[r // 2, c // 2]
        for c in range(width):
            phase = _angle(out[0, r, c], out[1, r, c])
            phi = phase + _TWO_PI * np.float32(np.rint((block_phase[c] - phase) * _INV_TWO_PI))
            taken[r, c] = phi
            z = (ca[r, c] + cb[r, c] * phi) / (da[r, c] + db[r, c] * phi)
            depth[r, c] = z if fringes[r, c] else nan
            sure[r, c] = block_confidence[c] if fringes[r, c] else nan
        miss = missed[r]
        miss[:] = 0
        for k in range(code_planes.shape[0]):
            num, den, a, b = out[code_planes[k], r], out[code_planes[k] + 1, r], intercepts[k, r], rates[k, r]
            for c in range(width):
                miss[c] += _wrapped_square(_angle(num[c], den[c]) - a[c] - b[c] * taken[r, c])
    return depth, sure, taken, missed


@numba.njit(nogil=True, error_model="numpy", cache=_CACHE)
def label_counts(labels, count, marked):
    """The pixels marked (a mask) of each label 0 .. count - 1 (cv2.connectedComponents' labels)."""
    counts = np.zeros(count, np.int64)
    for r in range(labels.shape[0]):
        for c in range(labels.shape[1]):
            if marked[r, c]:
                counts[labels[r, c]] += 1
    return counts


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def window_mean_residuals(depth, sums, counts):
    """model.local_depth's middle: each pixel's window mean (its window's depth sum over its count of
    known pixels, at least 1) and the square of its depth's difference from it (0 where unknown)."""
    mean = np.empty(depth.shape, np.float32)
    squares = np.empty(depth.shape, np.float32)
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            m = sums[r, c] / max(counts[r, c], np.float32(1))
            mean[r, c] = m
            z = depth[r, c]
            e = z - m if np.isfinite(z) else np.float32(0)
            squares[r, c] = e * e
    return mean, squares


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def window_roughness(depth, mean, square_sums, counts):
    """model.local_depth's end: the RMS of the window's squared differences (square_sums over its count
    of known pixels), and NaN in it and in mean (in place) where depth is unknown."""
    roughness = np.empty(depth.shape, np.float32)
    nan = np.float32(np.nan)
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            known = np.isfinite(depth[r, c])
            rms = np.sqrt(max(square_sums[r, c] / max(counts[r, c], np.float32(1)), np.float32(0)))
            roughness[r, c] = rms if known else nan
            mean[r, c] = mean[r, c] if known else nan
    return roughness


@numba.njit(nogil=True, cache=_CACHE)
def pixel_shuffle(x, r):
    """torch's PixelShuffle: (C r^2, H, W) -> (C, H r, W r), out[c, h r + i, w r + j] = x[c r^2 + i r + j, h, w]
    (a third of the time of cv2.merge's interleaving)."""
    c, h, w = x.shape[0] // (r * r), x.shape[1], x.shape[2]
    out = np.empty((c, h * r, w * r), x.dtype)
    for k in range(c):
        for y in range(h):
            for i in range(r):
                row = out[k, y * r + i]
                for j in range(r):
                    source = x[(k * r + i) * r + j, y]
                    for v in range(w):
                        row[v * r + j] = source[v]
    return out


@numba.njit(inline="always", fastmath=_FAST, error_model="numpy")
def _steady(z, a, b, c, d, step):
    """z is finite and none of its neighbours a to d is more than step away (_jump)."""
    return np.isfinite(z) & ~_jump(z, a, b, c, d, step)


@numba.njit(nogil=True, fastmath=_FAST, error_model="numpy", cache=_CACHE)
def steady_pixels(depth, max_step):
    """reconstruct.drop_flying_pixels: the finite pixels no finite 4-neighbour of which is more than
    max_step away (float32 comparisons; a NaN neighbour is no step, inf: no rule). A missing
    neighbour at the border is the pixel itself; the inner columns in a loop of their own, so that
    it vectorizes."""
    height, width = depth.shape
    step = np.float32(max_step)
    steady = np.empty((height, width), np.bool_)
    for r in range(height):
        up, row, down, out = depth[max(r - 1, 0)], depth[r], depth[min(r + 1, height - 1)], steady[r]
        for c in range(1, width - 1):
            out[c] = _steady(row[c], up[c], down[c], row[c - 1], row[c + 1], step)
        for c in (0, width - 1):
            out[c] = _steady(row[c], up[c], down[c], row[max(c - 1, 0)], row[min(c + 1, width - 1)], step)
    return steady
