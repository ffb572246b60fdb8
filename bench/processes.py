"""Stopping the subprocesses a benchmark started."""

import signal
import subprocess


def stop_all(processes: list[subprocess.Popen], sig: int = signal.SIGINT, timeout: float = 60) -> None:
    """Send `sig` to each process still running, wait up to `timeout` s for each, then kill what is left."""
    for process in processes:
        if process.poll() is None:
            process.send_signal(sig)
    for process in processes:
        try:
            process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
