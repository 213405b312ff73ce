"""What the stream benchmarks share (scripts/bench_stream.py, scripts/soak.py): nodes started the way a
user starts them (`ros2 run fpp_nodes ...`, one process each, logs to files), stopped with SIGINT,
capture_sequence's shutdown counts read back from its log, and percentile rows.

Run the scripts in the environment of scripts/env.bash; this module is imported from scripts/.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class NodeProcesses:
    """`ros2 run fpp_nodes EXE --ros-args ...` processes on one domain, each in its own session (so a
    signal reaches the whole process group) with stdout and stderr in LOGS/EXE.log."""

    def __init__(self, domain: int, logs: Path):
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1",
                        RCUTILS_LOGGING_BUFFERED_STREAM="0")
        self.logs, self.procs = Path(logs), []

    def start(self, executable: str, *ros_args: str) -> subprocess.Popen:
        log = open(self.logs / f"{executable}.log", "w")
        # ros2 run and the wheels' bootstrapper both exec, so this pid is the node's process
        proc = subprocess.Popen(["ros2", "run", "fpp_nodes", executable, "--ros-args", *ros_args], env=self.env,
                                stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        self.procs.append((proc, log))
        return proc

    def log(self, executable: str) -> str:
        return (self.logs / f"{executable}.log").read_text()

    def stop(self, timeout: float = 15.0) -> None:
        """SIGINT (the nodes print their counts and shut down cleanly), SIGKILL after timeout."""
        for proc, _ in self.procs:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        for proc, log in self.procs:
            try:
                proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            log.close()


@dataclass
class CaptureCounts:
    """capture_sequence's counts over its whole run, printed at shutdown."""
    frames_in: int
    complete: int
    dropped: int
    reasons: str  # e.g. "{'missing frame': 2}", empty when none
    unmatched: int  # camera frames that matched no projected pattern


CAPTURE_SUMMARY = re.compile(r"\[capture_sequence\] frames in (\d+), sequences complete (\d+), dropped (\d+)"
                             r"(?: (\{[^}]*\}))?, frames matching no pattern (\d+)")


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
