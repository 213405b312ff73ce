"""Where a benchmark ran: the lines every script in scripts/ prints above its table.

Standard library only, plus the libraries named in `libs` where they import (a missing one is left
out), so it also runs in .venv-opencv (scripts/bench_psp.py) without fpp_nodes or rclpy.
"""

from __future__ import annotations

import importlib
import os
import platform


def cpu() -> tuple[str, str]:
    """(model name, SIMD level) from /proc/cpuinfo; ("unknown", "unknown") where it cannot be read."""
    model, flags = "unknown", None
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and model == "unknown":
                    model = value.strip()
                elif key.strip() == "flags" and flags is None:
                    flags = set(value.split())
    except OSError:
        pass
    if flags is None:
        return model, "unknown"
    if (
        "avx512f" in flags
        and "X86_V4" in os.environ.get("NPY_DISABLE_CPU_FEATURES", "")
        and "AVX512" in os.environ.get("OPENCV_CPU_DISABLE", "")
    ):
        return model, "AVX2: its AVX-512 disabled for numpy and OpenCV by NPY_DISABLE_CPU_FEATURES, OPENCV_CPU_DISABLE"
    return model, "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "SSE/other"


def describe(threads: dict[str, int], libs=("numpy", "cv2", "onnxruntime")) -> str:
    """CPU model and SIMD level, logical cores, the thread counts the benchmark uses (label -> count),
    and the versions of python and of those of `libs` that import."""
    model, simd = cpu()
    versions = [f"python {platform.python_version()}"]
    for name in libs:
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        versions.append(f"{'opencv' if name == 'cv2' else name} {getattr(module, '__version__', '?')}")
    return "\n".join(
        [
            f"machine: {model} ({simd}), {os.cpu_count()} logical cores",
            "threads: " + ", ".join(f"{label} {n}" for label, n in threads.items()),
            "versions: " + ", ".join(versions),
        ]
    )
