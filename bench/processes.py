"""Starting subprocesses under another host name, and stopping those a benchmark started."""

import os
import signal
import subprocess


def on_host(name: str, command: list[str]) -> list[str]:
    """`command` run in a UTS namespace of its own whose host name is `name`, as a lab's robot PC and GPU box have
    (as root there; an unprivileged user is mapped to it)."""
    unshare = ["unshare", "--uts"] + ([] if os.geteuid() == 0 else ["--map-root-user"])
    return [*unshare, "sh", "-c", 'hostname "$0" && exec "$@"', name, *command]


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
