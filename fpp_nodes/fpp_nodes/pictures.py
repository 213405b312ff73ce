"""Pictures people look at rather than read: the demo, `fpp` and the training figures draw them.

    depth_picture   colour-mapped depth (turbo, near = red) with a colour bar in mm
    error_picture   signed error against ground truth (blue = too near, red = too far), colour bar, RMSE
    cloud_view      the point cloud from an oblique virtual camera, shaded, coloured by depth
    height_profile  depth along one image row for several sources (the paper's Figure 3)
    side_by_side    images in a row with captions (the paper's Figure 2)

Axes, colour bars, legends and text are matplotlib's, drawn off-screen (Agg, no pyplot state). The
cloud view is our own z-buffered splatting: matplotlib's 3-D axes cannot draw 300 000 points as a
closed surface. Every function returns a BGR uint8 image for cv2.imwrite; NaN marks invalid pixels
on the way in and is drawn in INVALID_BGR.
"""

from __future__ import annotations

import math

import cv2
import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from .core.calibration import CameraIntrinsics, back_project
from .core.metrics import depth_errors

INVALID_BGR = (96, 96, 96)
PAPER = (255, 255, 255)
DPI = 100
TITLE_HEIGHT = 24  # pixels above a picture for its title or caption
BAR_PANEL = 92  # pixels right of a picture for its colour bar and tick labels
FONT_SIZE = 8
# near = red: turbo from far (blue) to near (red); errors: blue = too near, white = 0, red = too far
DEPTH_COLOURS, ERROR_COLOURS = "turbo_r", "RdBu_r"
# curve colours (BGR) in the order curves are given: black, then a colour-blind-safe palette
PALETTE = ((0, 0, 0), (178, 114, 0), (0, 94, 213), (115, 158, 0), (167, 121, 204), (66, 228, 240), (233, 180, 86))


def _colour_map(name: str):
    return matplotlib.colormaps[name].with_extremes(bad=np.array(INVALID_BGR[::-1]) / 255)


def colours(values: np.ndarray, first: float, last: float, cmap: str = DEPTH_COLOURS) -> np.ndarray:
    """BGR uint8 of values mapped linearly from first to last of the colour map, clipped; NaN in
    INVALID_BGR."""
    rgba = _colour_map(cmap)(Normalize(first, last, clip=True)(np.ma.masked_invalid(values)), bytes=True)
    return np.ascontiguousarray(rgba[..., 2::-1])


def depth_colours(depth_mm: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """Depth in the colours of depth_picture, without its bar."""
    return colours(depth_mm, *depth_range(depth_mm, lo, hi))


def error_colours(error_mm: np.ndarray, limit_mm: float) -> np.ndarray:
    """Signed error in the colours of error_picture, without its bar."""
    return colours(error_mm, -limit_mm, limit_mm, ERROR_COLOURS)


def depth_range(depth: np.ndarray, lo=None, hi=None) -> tuple[float, float]:
    """The range depth pictures map: lo, hi, defaulting to the 1st and 99th percentiles of the
    finite values."""
    finite = np.asarray(depth)[np.isfinite(depth)]
    if finite.size == 0:
        return (0.0 if lo is None else lo), (1.0 if hi is None else hi)
    lo = float(np.percentile(finite, 1)) if lo is None else float(lo)
    hi = float(np.percentile(finite, 99)) if hi is None else float(hi)
    return lo, (hi if hi > lo else lo + 1e-3)


def _figure(width_px: int, height_px: int) -> Figure:
    return Figure(figsize=(width_px / DPI, height_px / DPI), dpi=DPI, facecolor="white")


def _axes_at(fig: Figure, left: int, top: int, width: int, height: int):
    """Axes at a pixel rectangle of the figure (top-left origin)."""
    w, h = fig.bbox.width, fig.bbox.height
    return fig.add_axes((left / w, 1 - (top + height) / h, width / w, height / h))


def _bgr(fig: Figure) -> np.ndarray:
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return cv2.cvtColor(np.asarray(canvas.buffer_rgba()), cv2.COLOR_RGBA2BGR)


def _with_colour_bar(
    values: np.ndarray, lo: float, hi: float, cmap: str, title: str | None, low_on_top: bool = False
) -> np.ndarray:
    """values at one picture pixel each (lo..hi over the colour map), a colour bar on the right, a
    title above."""
    h, w = values.shape
    top = TITLE_HEIGHT if title else 0
    fig = _figure(w + BAR_PANEL, h + top)
    ax = _axes_at(fig, 0, top, w, h)
    ax.set_axis_off()
    image = ax.imshow(values, _colour_map(cmap), Normalize(lo, hi), interpolation="nearest", aspect="auto")
    bar = fig.colorbar(image, cax=_axes_at(fig, w + 10, top + 12, 16, h - 24))
    if low_on_top:
        bar.ax.invert_yaxis()
    bar.ax.tick_params(labelsize=FONT_SIZE)
    bar.ax.set_title("mm", fontsize=FONT_SIZE, loc="left")
    if title:
        fig.text(4 / fig.bbox.width, 1 - 6 / fig.bbox.height, title, fontsize=FONT_SIZE + 1, va="top")
    return _bgr(fig)


def depth_picture(
    depth_mm: np.ndarray, lo: float | None = None, hi: float | None = None, title: str | None = None
) -> np.ndarray:
    """Colour-mapped depth (near = red) with a colour bar in mm (near at the top); range lo..hi
    defaults to the 1st..99th percentile of the valid pixels; NaN in INVALID_BGR."""
    lo, hi = depth_range(depth_mm, lo, hi)
    return _with_colour_bar(np.asarray(depth_mm, np.float64), lo, hi, DEPTH_COLOURS, title, low_on_top=True)


def error_picture(
    pred_mm: np.ndarray, truth_mm: np.ndarray, limit_mm: float | None = None, title: str | None = None
) -> np.ndarray:
    """pred - truth in a blue-white-red map over [-limit, +limit] (default: the 99th percentile of
    |error|), colour bar in mm, and a title with the RMSE over the pixels valid in both."""
    mask = np.isfinite(pred_mm) & np.isfinite(truth_mm)
    error = np.where(mask, np.asarray(pred_mm, np.float64) - truth_mm, np.nan)
    if limit_mm is None:
        limit_mm = float(np.percentile(np.abs(error[mask]), 99)) if mask.any() else 1.0
    limit_mm = max(limit_mm, 1e-3)
    value = depth_errors(pred_mm, truth_mm).rmse_mm
    summary = f"RMSE {value:.3g} mm over {int(mask.sum())} px" if mask.any() else "no pixel valid in both"
    title = f"{title}: {summary}" if title else f"error, {summary}"
    return _with_colour_bar(error, -limit_mm, limit_mm, ERROR_COLOURS, title)


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
        tint = depth_colours(xyz[:, 2], lo, hi).astype(np.float32)
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
    """Curves (name -> 1-D array; NaN = no value) on shared axes with a legend, as the paper's Figure 3
    draws the height along one line of the image. Element i is at x_start + i; ylim (low, high)
    defaults to all finite values. Colours follow PALETTE in the order given (the first, the
    reference, drawn thin and on top) unless colours (name -> BGR) says otherwise."""
    fig = _figure(*size)
    ax = fig.add_axes((64 / size[0], 42 / size[1], 1 - 76 / size[0], 1 - 72 / size[1]))
    for k, (name, curve) in enumerate(curves.items()):
        bgr = (colours or {}).get(name, PALETTE[k % len(PALETTE)])
        curve = np.asarray(curve, np.float64).ravel()
        ax.plot(
            x_start + np.arange(curve.size),
            curve,
            color=np.array(bgr[::-1]) / 255,
            label=name,
            linewidth=1 if k == 0 else 2,
            zorder=3 if k == 0 else 2,
        )
    if ylim is not None:
        ax.set_ylim(*ylim)
    ax.grid(axis="y", color="0.9")
    ax.set_xlabel(xlabel, fontsize=FONT_SIZE + 1)
    ax.set_ylabel(ylabel, fontsize=FONT_SIZE + 1)
    ax.tick_params(labelsize=FONT_SIZE)
    ax.set_title(
        title if title is not None else (f"along row {row_index}" if row_index is not None else ""),
        fontsize=FONT_SIZE + 1,
        loc="right",
    )
    ax.legend(loc="upper right", fontsize=FONT_SIZE)
    return _bgr(fig)


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


def side_by_side(images: list, captions: list | None = None, height: int | None = None, gap: int = 6) -> np.ndarray:
    """Images (BGR or grey uint8) in a row, scaled to one height (default: the first's), each under
    its caption if captions are given."""
    if captions is not None and len(captions) != len(images):
        raise ValueError(f"{len(images)} images but {len(captions)} captions")
    height = height or images[0].shape[0]
    tiles = []
    for img in images:
        img = np.asarray(img)
        if img.dtype != np.uint8:
            raise ValueError(f"side_by_side takes uint8 images, got {img.dtype}")
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        if img.shape[0] != height:
            w = max(1, round(img.shape[1] * height / img.shape[0]))
            shrink = img.shape[0] > height
            img = cv2.resize(img, (w, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        tiles.append(img)
    width = sum(t.shape[1] for t in tiles) + gap * (len(tiles) - 1)
    top = TITLE_HEIGHT if captions is not None else 0
    fig = _figure(width, height + top)
    left = 0
    for k, tile in enumerate(tiles):
        ax = _axes_at(fig, left, top, tile.shape[1], height)
        ax.set_axis_off()
        ax.imshow(tile[..., ::-1], interpolation="nearest", aspect="auto")
        if captions is not None:
            fig.text((left + 4) / width, 1 - 6 / (height + top), captions[k] or "", fontsize=FONT_SIZE + 1, va="top")
        left += tile.shape[1] + gap
    return _bgr(fig)
