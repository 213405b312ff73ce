"""Nodes started the way a user starts them, one process each: for the demo, the benchmarks and the
tests. Each process runs in its own session, so a signal reaches all it started, with its output in a
log file; it is stopped with SIGINT (nodes print their counts and shut down cleanly), SIGKILL after a
timeout."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path


def start_process(args: list[str], env: dict, stdout, stderr=subprocess.STDOUT) -> subprocess.Popen:
    return subprocess.Popen(args, env=env, stdout=stdout, stderr=stderr, start_new_session=True)


def stop_process(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
    _wait_or_kill(proc, timeout)


def _wait_or_kill(proc: subprocess.Popen, timeout: float) -> None:
    """One SIGINT only: a second one can land in the node's own shutdown."""
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


class NodeProcesses:
    """`ros2 run fpp_nodes EXE --ros-args ...` processes on one ROS domain, logs in LOGS/EXE-N.log.
    env: the environment of scripts/env.bash (default: this process's own)."""

    def __init__(self, domain_id: int, logs: Path, env: dict | None = None):
        self.domain_id, self.logs_dir, self.procs = domain_id, Path(logs), []
        self.env = dict(
            os.environ if env is None else env,
            ROS_DOMAIN_ID=str(domain_id),
            PYTHONUNBUFFERED="1",
            RCUTILS_LOGGING_BUFFERED_STREAM="0",
        )

    def start(self, executable: str, *ros_args: str, env: dict | None = None) -> subprocess.Popen:
        """env: more environment variables for this process only."""
        log = open(self.logs_dir / f"{executable}-{len(self.procs)}.log", "w")
        # ros2 run and the wheels' bootstrapper both exec, so this pid is the node's process
        args = ["ros2", "run", "fpp_nodes", executable] + (["--ros-args", *ros_args] if ros_args else [])
        proc = start_process(args, {**self.env, **(env or {})}, log)
        self.procs.append((executable, proc, log))
        return proc

    def logs(self, executable: str | None = None) -> str:
        """Everything the processes (of one executable, if named) have written so far."""
        return "\n".join(Path(log.name).read_text() for exe, _, log in self.procs if executable in (None, exe))

    def stop(self, timeout: float = 10.0) -> None:
        for _, proc, _ in self.procs:  # all at once, so none waits for another's timeout
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        for _, proc, log in self.procs:
            _wait_or_kill(proc, timeout)
            log.close()
