"""Pictures people look at rather than read, drawn with numpy and cv2 only (the nodes import this).

    depth_picture   colour-mapped depth (turbo, near = red) with a scale bar in mm
    error_picture   signed error against ground truth (blue = too near, red = too far), scale bar, RMSE
    cloud_view      the point cloud from an oblique virtual camera, shaded, coloured by depth
    height_profile  depth along one image row for several sources (the paper's Figure 3)
    side_by_side    images in a row with captions (the paper's Figure 2)

Every function returns a BGR uint8 image for cv2.imwrite; NaN marks invalid pixels on the way in and
is drawn in INVALID_BGR.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .core.calibration import CameraIntrinsics, back_project
from .core.metrics import depth_errors

INVALID_BGR = (96, 96, 96)
PAPER, INK = (255, 255, 255), (0, 0, 0)
FONT, FONT_SCALE = cv2.FONT_HERSHEY_SIMPLEX, 0.45
# scale bar layout, right of the image: gap, bar, then tick labels; the bar spans rows
# [BAR_MARGIN, height - 1 - BAR_MARGIN] of the image, the colour map's end at the top
BAR_GAP, BAR_WIDTH, BAR_PANEL, BAR_MARGIN = 10, 16, 92, 12
TITLE_HEIGHT = 24
# curve colours (BGR) in the order curves are given: black, then a colour-blind-safe palette
PALETTE = (
    (0, 0, 0),
    (178, 114, 0),
    (0, 94, 213),
    (115, 158, 0),
    (167, 121, 204),
    (66, 228, 240),
    (233, 180, 86),
    (0, 159, 230),
)


def _diverging_lut() -> np.ndarray:
    """256 x 1 BGR table: blue -> white -> red."""
    s = (np.arange(256) - 127.5) / 127.5
    blue, red, white = np.array([172, 84, 33]), np.array([38, 30, 178]), np.array([247, 247, 247])
    end = np.where(s[:, None] < 0, blue, red)
    return np.rint(white * (1 - np.abs(s[:, None])) + end * np.abs(s[:, None])).astype(np.uint8)[:, None, :]


DIVERGING = _diverging_lut()


def _colour(values: np.ndarray, first: float, last: float, colormap=cv2.COLORMAP_TURBO) -> np.ndarray:
    """Values mapped linearly from first (start of the colour map) to last (its end), clipped;
    NaN in INVALID_BGR. colormap is a cv2 COLORMAP_* or a 256 x 1 BGR table."""
    values = np.asarray(values, np.float64)
    finite = np.isfinite(values)
    span = last - first if abs(last - first) > 1e-12 else 1e-12
    t = np.clip((np.where(finite, values, first) - first) / span, 0.0, 1.0)
    index = np.rint(t * 255).astype(np.uint8)
    picture = cv2.applyColorMap(index if index.ndim == 2 else index[None], colormap)
    picture = picture.reshape(values.shape + (3,))
    picture[~finite] = INVALID_BGR
    return picture


def depth_range(depth: np.ndarray, lo=None, hi=None) -> tuple[float, float]:
    """The range depth pictures map: lo, hi, defaulting to the 1st and 99th percentiles of the
    finite values."""
    finite = np.asarray(depth)[np.isfinite(depth)]
    if finite.size == 0:
        return (0.0 if lo is None else lo), (1.0 if hi is None else hi)
    lo = float(np.percentile(finite, 1)) if lo is None else float(lo)
    hi = float(np.percentile(finite, 99)) if hi is None else float(hi)
    return lo, (hi if hi > lo else lo + 1e-3)


def _ticks(a: float, b: float, count: int = 5) -> tuple[np.ndarray, int]:
    """Round tick values (1, 2, 5 x 10^k apart) within [min(a, b), max(a, b)] and the decimals they need."""
    lo, hi = min(a, b), max(a, b)
    raw = max(hi - lo, 1e-9) / max(count - 1, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 5, 10) if m * power >= raw * 0.999)
    values = np.arange(math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9) + 1) * step
    return values, max(0, -math.floor(math.log10(step) + 1e-9))


def _text(img, text: str, org, scale: float = FONT_SCALE, colour=INK) -> None:
    cv2.putText(img, text, (int(org[0]), int(org[1])), FONT, scale, colour, 1, cv2.LINE_AA)


def _text_width(text: str, scale: float = FONT_SCALE) -> int:
    return cv2.getTextSize(text, FONT, scale, 1)[0][0]


def _titled(img: np.ndarray, title: str | None, height: int = TITLE_HEIGHT) -> np.ndarray:
    """img with a white strip above it holding the title (left-aligned), if there is one."""
    if not title:
        return img
    strip = np.full((height, img.shape[1], 3), PAPER, np.uint8)
    _text(strip, title, (4, height - 8))
    return np.vstack([strip, img])


def _with_scale_bar(picture: np.ndarray, first: float, last: float, colormap, unit: str = "mm") -> np.ndarray:
    """picture with a colour bar on its right: `last` at the top, `first` at the bottom (the colour
    map's end at the top), round values ticked and labelled."""
    h, w = picture.shape[:2]
    canvas = np.full((h, w + BAR_PANEL, 3), PAPER, np.uint8)
    canvas[:, :w] = picture
    top, bottom = BAR_MARGIN, h - 1 - BAR_MARGIN
    rows = np.arange(top, bottom + 1)
    values = last + (first - last) * (rows - top) / max(bottom - top, 1)
    x0 = w + BAR_GAP
    canvas[top : bottom + 1, x0 : x0 + BAR_WIDTH] = _colour(values, first, last, colormap)[:, None]
    cv2.rectangle(canvas, (x0 - 1, top - 1), (x0 + BAR_WIDTH, bottom + 1), INK, 1)
    ticks, decimals = _ticks(first, last)
    for v in ticks:
        y = top + (last - v) / (last - first) * (bottom - top)
        cv2.line(canvas, (x0 + BAR_WIDTH, int(round(y))), (x0 + BAR_WIDTH + 4, int(round(y))), INK, 1)
        _text(canvas, f"{v:.{decimals}f}", (x0 + BAR_WIDTH + 7, y + 4))
    _text(canvas, unit, (x0, BAR_MARGIN - 3), 0.4)
    return canvas


def depth_colours(depth_mm: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """Colour-mapped depth without a bar: turbo from far (lo..hi: hi = blue) to near (lo = red)."""
    lo, hi = depth_range(depth_mm, lo, hi)
    return _colour(depth_mm, hi, lo)


def depth_picture(
    depth_mm: np.ndarray, lo: float | None = None, hi: float | None = None, title: str | None = None
) -> np.ndarray:
    """Colour-mapped depth (near = red) with a scale bar in mm (near at the top); range lo..hi
    defaults to the 1st..99th percentile of the valid pixels; NaN in INVALID_BGR."""
    lo, hi = depth_range(depth_mm, lo, hi)
    return _titled(_with_scale_bar(depth_colours(depth_mm, lo, hi), hi, lo, cv2.COLORMAP_TURBO, "mm"), title)


def error_picture(
    pred_mm: np.ndarray, truth_mm: np.ndarray, limit_mm: float | None = None, title: str | None = None
) -> np.ndarray:
    """pred - truth in a blue-white-red map over [-limit, +limit] (default: the 99th percentile of
    |error|), scale bar in mm, and a title with the RMSE over the pixels valid in both."""
    mask = np.isfinite(pred_mm) & np.isfinite(truth_mm)
    error = np.where(mask, np.asarray(pred_mm, np.float64) - truth_mm, np.nan)
    if limit_mm is None:
        limit_mm = float(np.percentile(np.abs(error[mask]), 99)) if mask.any() else 1.0
    limit_mm = max(limit_mm, 1e-3)
    picture = _with_scale_bar(_colour(error, -limit_mm, limit_mm, DIVERGING), -limit_mm, limit_mm, DIVERGING, "mm")
    value = depth_errors(pred_mm, truth_mm).rmse_mm
    summary = f"RMSE {value:.3g} mm over {int(mask.sum())} px" if mask.any() else "no pixel valid in both"
    return _titled(picture, f"{title}: {summary}" if title else f"error, {summary}")


def _rotation(tilt_deg: float, turn_deg: float) -> np.ndarray:
    a, b = math.radians(tilt_deg), math.radians(turn_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    return rx @ ry


def _rotate(rot: np.ndarray, points: np.ndarray) -> np.ndarray:
    """rot @ each row of points (N, 3), without BLAS (its threads only wait on a busy machine)."""
    return (points[:, :1] * rot[:, 0] + points[:, 1:2] * rot[:, 1] + points[:, 2:] * rot[:, 2]).astype(np.float32)


def _normals(xyz: np.ndarray) -> np.ndarray:
    """Unit normals of an organized cloud from its row and column neighbours, facing the camera
    (NaN where a neighbour is missing)."""
    pad = np.pad(xyz, ((1, 1), (1, 1), (0, 0)), constant_values=np.nan)
    du = pad[1:-1, 2:] - pad[1:-1, :-2]
    dv = pad[2:, 1:-1] - pad[:-2, 1:-1]
    n = np.stack(
        [
            du[..., 2] * dv[..., 1] - du[..., 1] * dv[..., 2],
            du[..., 0] * dv[..., 2] - du[..., 2] * dv[..., 0],
            du[..., 1] * dv[..., 0] - du[..., 0] * dv[..., 1],
        ],
        axis=-1,
    )  # dv x du: towards the camera
    with np.errstate(invalid="ignore", divide="ignore"):
        return n / np.sqrt(np.sum(n * n, axis=-1, keepdims=True))


def cloud_view(
    points: np.ndarray,
    camera: CameraIntrinsics | None = None,
    size=(480, 360),
    tilt_deg: float = 30.0,
    turn_deg: float = -25.0,
    step: int | None = None,
    colour: str = "depth",
    lo: float | None = None,
    hi: float | None = None,
    background=PAPER,
) -> np.ndarray:
    """The cloud as a surface seen from an oblique virtual camera.

    points: an organized (H, W, 3) cloud in the optical frame (x right, y down, z forward; any unit),
    or an (H, W) depth map with its camera's intrinsics. The cloud is turned about its centroid by
    turn_deg about the vertical and tilt_deg about the horizontal axis (positive: seen from above),
    projected with a pinhole fitted to size (width, height), z-buffered, and shaded (Lambert, a light
    above left of the viewer) from normals of the grid neighbours; colour "depth" tints it with the
    depth colours of depth_picture (lo/hi as there, in the input's unit), anything else leaves it grey.
    step takes every step-th row and column (default: about one point per pixel of the view).
    """
    if points.ndim == 2:
        if camera is None:
            raise ValueError("cloud_view of a depth map needs the camera intrinsics")
        points = back_project(points, camera)
    width, height = size
    step = step or max(1, math.ceil(math.sqrt(points.shape[0] * points.shape[1] / (width * height))))
    grid = np.asarray(points[::step, ::step], np.float32)
    canvas = np.full((height, width, 3), background, np.uint8)
    keep = np.all(np.isfinite(grid), axis=-1)
    if keep.sum() < 3:
        return canvas
    xyz, normals = grid[keep], _normals(grid)[keep]
    if colour == "depth":
        lo, hi = depth_range(xyz[:, 2], lo, hi)
        tint = _colour(xyz[:, 2], hi, lo).astype(np.float32)
    else:
        tint = np.full((len(xyz), 3), 215.0, np.float32)
    rot = _rotation(-tilt_deg, turn_deg)  # y is down: a view from above turns the top towards us
    p = _rotate(rot, xyz - np.median(xyz, axis=0))
    n = _rotate(rot, normals)
    extent = float(np.percentile(np.abs(p), 99.5)) or 1.0
    p[:, 2] += 4.0 * extent  # the virtual camera, on the axis through the centroid
    x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    x0, x1 = np.percentile(x, (0.2, 99.8))
    y0, y1 = np.percentile(y, (0.2, 99.8))
    f = 0.92 * min(width / max(x1 - x0, 1e-12), height / max(y1 - y0, 1e-12))
    u, v = f * (x - (x0 + x1) / 2) + width / 2, f * (y - (y0 + y1) / 2) + height / 2
    light = np.array([-0.45, -0.6, -1.0]) / np.linalg.norm([-0.45, -0.6, -1.0])  # above left of the viewer
    shade = np.nan_to_num(np.clip(n[:, 0] * light[0] + n[:, 1] * light[1] + n[:, 2] * light[2], 0, 1), nan=0.7)
    rgb = np.clip(tint * (0.3 + 0.75 * shade[:, None]), 0, 255).astype(np.uint8)
    # each point covers a square as wide as the gap to its grid neighbours on screen (at most 6 px),
    # so slanted surfaces stay closed; the nearest point wins each pixel
    sizes = _splat_sizes(keep, u, v)
    ui, vi = np.rint(u).astype(np.int32), np.rint(v).astype(np.int32)
    us, vs, which = [], [], []
    for s in np.unique(sizes):
        pick = np.flatnonzero(sizes == s)
        du, dv = (a.ravel() for a in np.meshgrid(np.arange(-(s // 2), s - s // 2), np.arange(-(s // 2), s - s // 2)))
        us.append((ui[pick, None] + du).ravel())
        vs.append((vi[pick, None] + dv).ravel())
        which.append(np.repeat(pick, s * s))
    u, v, which = np.concatenate(us), np.concatenate(vs), np.concatenate(which)
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    index, which = v[inside] * width + u[inside], which[inside]
    z = p[which, 2]
    zbuf = np.full(width * height, np.inf, np.float32)
    np.minimum.at(zbuf, index, z)
    front = z <= zbuf[index]
    canvas.reshape(-1, 3)[index[front]] = rgb[which[front]]
    return canvas


def _splat_sizes(keep: np.ndarray, u: np.ndarray, v: np.ndarray, largest: int = 6) -> np.ndarray:
    """Per kept point of a grid: its splat's width, the screen distance to its farther kept right or
    lower grid neighbour plus a fifth (rounding leaves no pin holes), rounded up, 1..largest px."""
    gu, gv = np.full(keep.shape, np.nan, np.float32), np.full(keep.shape, np.nan, np.float32)
    gu[keep], gv[keep] = u, v
    gap = np.zeros(keep.shape, np.float32)
    with np.errstate(invalid="ignore"):
        gap[:, :-1] = np.fmax(np.abs(gu[:, 1:] - gu[:, :-1]), np.abs(gv[:, 1:] - gv[:, :-1]))
        gap[:-1] = np.fmax(gap[:-1], np.fmax(np.abs(gu[1:] - gu[:-1]), np.abs(gv[1:] - gv[:-1])))
    return np.clip(np.ceil(1.2 * np.nan_to_num(gap[keep], nan=1.0)), 1, largest).astype(np.int32)


def height_profile(
    row_index: int | None,
    curves: dict,
    size=(640, 360),
    ylabel: str = "depth (mm)",
    xlabel: str = "image column (px)",
    title: str | None = None,
    ylim=None,
    colours: dict | None = None,
    x_start: int = 0,
) -> np.ndarray:
    """Curves (name -> 1-D array; NaN = no value) on shared axes with ticks and a legend, as the
    paper's Figure 3 draws the height along one line of the image. Element i is at x_start + i;
    ylim (low, high) defaults to all finite values. Colours follow PALETTE in the order given (the
    first, the reference, drawn thin and on top) unless colours (name -> BGR) says otherwise."""
    width, height = size
    colour_of = {name: (colours or {}).get(name, PALETTE[k % len(PALETTE)]) for k, name in enumerate(curves)}
    img = np.full((height, width, 3), PAPER, np.uint8)
    left, right, top, bottom = 64, 12, 30, 42
    x0, x1, y0, y1 = left, width - right, top, height - bottom
    arrays = {name: np.asarray(c, np.float64).ravel() for name, c in curves.items()}
    n = max((len(a) for a in arrays.values()), default=1)
    if ylim is None:
        finite = np.concatenate([a[np.isfinite(a)] for a in arrays.values()] + [np.zeros(0)])
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        pad = 0.06 * max(hi - lo, 1e-6)
        ylim = (lo - pad, hi + pad)
    ymin, ymax = ylim

    def px(i, value):
        return (
            x0 + (x1 - x0) * np.asarray(i) / max(n - 1, 1),
            y1 - (y1 - y0) * (np.asarray(value) - ymin) / max(ymax - ymin, 1e-12),
        )

    cv2.rectangle(img, (x0, y0), (x1, y1), INK, 1)
    ticks, decimals = _ticks(ymin, ymax)
    for t in ticks:
        y = int(round(px(0, t)[1]))
        cv2.line(img, (x0 - 4, y), (x0, y), INK, 1)
        cv2.line(img, (x0 + 1, y), (x1 - 1, y), (230, 230, 230), 1)
        label = f"{t:.{decimals}f}"
        _text(img, label, (x0 - 7 - _text_width(label), y + 4))
    xticks, _ = _ticks(x_start, x_start + n - 1)
    for t in xticks:
        x = int(round(px(t - x_start, 0)[0]))
        cv2.line(img, (x, y1), (x, y1 + 4), INK, 1)
        _text(img, f"{t:.0f}", (x - _text_width(f"{t:.0f}") / 2, y1 + 17))
    _text(img, xlabel, ((x0 + x1 - _text_width(xlabel)) / 2, height - 6))
    _text(img, ylabel, (4, top - 10))
    heading = title if title is not None else (f"along row {row_index}" if row_index is not None else "")
    _text(img, heading, (x1 - _text_width(heading), top - 10))
    plot = img[y0 + 1 : y1, x0 + 1 : x1]  # curves are clipped to the axes
    for k, (name, a) in reversed(list(enumerate(arrays.items()))):  # the first (the reference) on top
        xs, ys = px(np.arange(len(a)), a)
        ok = np.isfinite(ys)
        breaks = np.flatnonzero(np.diff(ok.astype(np.int8)) != 0) + 1
        for segment in np.split(np.arange(len(a)), breaks):
            if ok[segment[0]]:
                pts = np.stack([xs[segment] - x0 - 1, ys[segment] - y0 - 1], axis=1)
                pts = np.clip(np.rint(pts), -10_000, 10_000).astype(np.int32)
                cv2.polylines(plot, [pts], False, colour_of[name], 1 if k == 0 else 2, cv2.LINE_AA)
    # legend, top right inside the axes
    names = list(arrays)
    box_w = 34 + max((_text_width(s) for s in names), default=0)
    bx, by = x1 - box_w - 6, y0 + 6
    cv2.rectangle(img, (bx, by), (x1 - 6, by + 8 + 16 * len(names)), PAPER, -1)
    cv2.rectangle(img, (bx, by), (x1 - 6, by + 8 + 16 * len(names)), (150, 150, 150), 1)
    for k, name in enumerate(names):
        y = by + 14 + 16 * k
        cv2.line(img, (bx + 6, y - 4), (bx + 26, y - 4), colour_of[name], 3)
        _text(img, name, (bx + 30, y))
    return img


def profile_row(depth_mm: np.ndarray) -> int:
    """The row whose valid depths vary most among rows at least a quarter valid (it crosses the
    objects): a default line for height_profile."""
    depth = np.asarray(depth_mm, np.float64)
    valid = np.isfinite(depth)
    valid &= valid.sum(axis=1, keepdims=True) >= max(depth.shape[1] // 4, 1)
    count = np.maximum(valid.sum(axis=1), 1)
    mean = np.where(valid, depth, 0).sum(axis=1) / count
    spread = (np.where(valid, depth - mean[:, None], 0) ** 2).sum(axis=1) / count
    return int(np.argmax(spread)) if valid.any() else depth.shape[0] // 2


def side_by_side(
    images: list,
    captions: list | None = None,
    height: int | None = None,
    gap: int = 6,
    caption_height: int = TITLE_HEIGHT,
) -> np.ndarray:
    """Images (BGR or grey uint8) in a row, scaled to one height (default: the first's), each under
    its caption if captions are given."""
    if captions is not None and len(captions) != len(images):
        raise ValueError(f"{len(images)} images but {len(captions)} captions")
    height = height or images[0].shape[0]
    tiles = []
    for k, img in enumerate(images):
        img = np.asarray(img)
        if img.dtype != np.uint8:
            raise ValueError(f"side_by_side takes uint8 images, got {img.dtype}")
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        if img.shape[0] != height:
            w = max(1, round(img.shape[1] * height / img.shape[0]))
            img = cv2.resize(
                img, (w, height), interpolation=cv2.INTER_AREA if img.shape[0] > height else cv2.INTER_LINEAR
            )
        tile = img if captions is None else _titled(img, captions[k] or " ", caption_height)
        tiles += [tile, np.full((tile.shape[0], gap, 3), PAPER, np.uint8)]
    return np.hstack(tiles[:-1])
