"""Files people bring and take away: fringe image stacks, depth maps, point clouds, pictures."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


class InputError(ValueError):
    """A file or folder that cannot be used as asked."""


def image_paths(inputs) -> list[Path]:
    """Expand folders to their images (sorted by name); keep files in the order given."""
    paths: list[Path] = []
    for item in map(Path, inputs):
        if item.is_dir():
            found = sorted(
                p for p in item.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.stem.startswith("fringe")
            )
            if not found:
                raise InputError(f"{item} holds no fringe_*.png / .tif images")
            paths += found
        elif item.is_file():
            paths.append(item)
        else:
            raise InputError(f"{item} does not exist")
    return paths


def read_image(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"cannot read image {path} (missing, truncated or not an image)")
    if img.ndim == 3:  # a colour capture of grey fringes: use its luminance
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.dtype not in (np.uint8, np.uint16, np.float32):
        raise InputError(f"{path}: pixel type {img.dtype} is not supported (8- or 16-bit, or 32-bit float)")
    return img


def read_stack(paths) -> np.ndarray:
    """(K, H, W) stack of same-sized, same-typed images."""
    images = [read_image(p) for p in paths]
    for p, img in zip(paths, images):
        if img.shape != images[0].shape or img.dtype != images[0].dtype:
            raise InputError(
                f"{p} is {img.shape[1]}x{img.shape[0]} {img.dtype}, but {paths[0]} is "
                f"{images[0].shape[1]}x{images[0].shape[0]} {images[0].dtype}"
            )
    return np.stack(images)


def write_stack(folder, images: np.ndarray) -> list[Path]:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    width = max(2, len(str(len(images) - 1)))
    paths = [folder / f"fringe_{i:0{width}d}.png" for i in range(len(images))]
    for p, img in zip(paths, images):
        cv2.imwrite(str(p), img)
    return paths


def read_depth(path) -> np.ndarray:
    """A depth map in millimetres from .npy or a 32-bit float TIFF (NaN where invalid)."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        try:
            depth = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read {path}: {e}") from None
    else:
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if depth is None:
            raise InputError(f"cannot read depth map {path}")
    if depth.ndim != 2 or depth.dtype.kind != "f":
        raise InputError(f"{path} must be a 2-D float depth map, got {depth.dtype} {depth.shape}")
    return depth


def write_depth(folder, name: str, depth_mm: np.ndarray) -> None:
    np.save(Path(folder) / f"{name}.npy", depth_mm.astype(np.float32))
    cv2.imwrite(str(Path(folder) / f"{name}.tiff"), depth_mm.astype(np.float32))


def write_ply(path, xyz: np.ndarray, grey: np.ndarray | None = None) -> int:
    """Binary PLY of an organized (H, W, 3) cloud: all H x W vertices in row-major order, NaN where
    invalid, with the grid's size in obj_info lines as PCL writes them; grey colour if given.
    Returns the number of valid points."""
    h, w = xyz.shape[:2]
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if grey is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rows = np.empty(h * w, fields)
    for i, axis in enumerate("xyz"):
        rows[axis] = xyz[..., i].reshape(-1)
    if grey is not None:
        g = np.asarray(grey, np.float64)
        g8 = np.clip(g / max(float(g.max()), 1e-9) * 255, 0, 255).astype(np.uint8).reshape(-1)
        rows["red"] = rows["green"] = rows["blue"] = g8
    header = [
        "ply",
        "format binary_little_endian 1.0",
        f"obj_info num_cols {w}",
        f"obj_info num_rows {h}",
        f"element vertex {h * w}",
    ]
    header += [f"property {'float' if t == '<f4' else 'uchar'} {n}" for n, t in fields]
    header.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode())
        f.write(rows.tobytes())
    return int(np.count_nonzero(np.all(np.isfinite(xyz), axis=-1)))
