"""What the stream benchmarks share (scripts/bench_stream.py, scripts/soak.py, scripts/bench_cnn.py):
capture_sequence's shutdown counts read back from its log, percentile rows, a process's memory and the
CPU time of a process and its children (the nodes are started with fpp_nodes.processes).

Run the scripts in the environment of scripts/env.bash; this module is imported from scripts/.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class CaptureCounts:
    """capture_sequence's counts over its whole run, printed at shutdown."""

    frames_in: int
    complete: int
    dropped: int
    reasons: str  # e.g. "{'missing frame': 2}", empty when none
    unmatched: int  # camera frames that matched no projected pattern


CAPTURE_SUMMARY = re.compile(
    r"\[capture_sequence\] frames in (\d+), sequences complete (\d+), dropped (\d+)"
    r"(?: (\{[^}]*\}))?, frames matching no pattern (\d+)"
)


def capture_counts(log: str) -> CaptureCounts | None:
    """The summary line capture_sequence prints when it is destroyed, or None if it never printed one."""
    m = CAPTURE_SUMMARY.search(log)
    if not m:
        return None
    return CaptureCounts(int(m[1]), int(m[2]), int(m[3]), m[4] or "", int(m[5]))


def percentile_row(label: str, values_ms, width: int = 16, percentiles=(50, 95)) -> str:
    """'label  p.. p.. max' in ms; dashes where there are no values."""
    values = np.asarray(values_ms, dtype=float)
    cells = [np.percentile(values, p) for p in percentiles] + [values.max()] if values.size else []
    body = " ".join(f"{v:7.1f}" for v in cells) if cells else " ".join(f"{'-':>7}" for _ in range(len(percentiles) + 1))
    return f"{label:{width}} {body}"


def percentile_header(label: str, width: int = 16, percentiles=(50, 95)) -> str:
    return f"{label:{width}} " + " ".join(f"{'p' + str(p):>7}" for p in percentiles) + f" {'max':>7}"


def rss_mb(pid: int) -> float | None:
    """Resident memory of a process (VmRSS), MB; None once it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def process_tree(pid: int) -> list[Path]:
    """/proc of a process and its descendants (a stock `ros2 run` starts the node as its child); those
    that cannot be read are left out."""
    procs, todo = [], [pid]
    while todo:
        proc = Path(f"/proc/{todo.pop()}")
        try:
            tasks = list((proc / "task").iterdir())
        except OSError:  # gone
            continue
        procs.append(proc)
        for task in tasks:
            try:
                todo += [int(c) for c in (task / "children").read_text().split()]
            except OSError:  # a thread that ended meanwhile: the process stays in the tree
                continue
    return procs


def process_times(pid: int) -> np.ndarray:
    """(user s, system s, minor page faults) of a process and its descendants so far."""
    ticks, total = os.sysconf("SC_CLK_TCK"), np.zeros(3)
    for proc in process_tree(pid):
        try:
            fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()  # from field 3, the state
        except OSError:
            continue
        total += [int(fields[11]) / ticks, int(fields[12]) / ticks, int(fields[7])]
    return total
