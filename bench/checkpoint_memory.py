"""Peak memory of saving and loading a checkpoint with a large replay buffer, on a local path and on S3.

    python bench/checkpoint_memory.py [--capacity 50000]

Starts moto's S3 server on 127.0.0.1 (the dev extras), then saves and loads a checkpoint whose replay buffer holds
2 x capacity + 2 frames of 48x48x3 (50,000: 659 MiB), each case in a fresh process, and prints its VmHWM (the
peak resident memory, reset just before the save / load) above the memory the process held before.
"""

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _status(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key):
            return int(line.split()[1]) / 1024
    raise RuntimeError(key)


def _reset_peak() -> None:
    Path("/proc/self/clear_refs").write_text("5")  # VmHWM back to the current RSS


def case(kind: str, url: str, capacity: int) -> None:
    sys.path.insert(0, str(ROOT))
    from learner.checkpoint import load_checkpoint, save_checkpoint
    from learner.replay import ReplayBuffer

    replay = ReplayBuffer(capacity, (48, 48, 3), 2)
    replay.frames[:] = 7
    replay.frames_added, replay.added = replay.frame_capacity, capacity
    for name in ("obs_slot", "next_slot", "actions", "not_done", "success"):
        getattr(replay, name)[:] = 1
    where = url.split(":")[0] if "://" in url else "local"
    _reset_peak()
    before, started = _status("VmRSS"), time.monotonic()
    if kind == "save":
        size = save_checkpoint(url, {"version": 1, "step": 1, "replay": replay.state_dict()})
        print(
            f"save {where}: frames {replay.frames.nbytes / 2**20:.0f} MiB, file {size / 2**20:.0f} MiB, RSS before "
            f"{before:.0f} MiB, peak {_status('VmHWM'):.0f} MiB (+{_status('VmHWM') - before:.0f}), "
            f"{time.monotonic() - started:.1f} s",
            flush=True,
        )
    else:
        state = load_checkpoint(url)
        assert state is not None
        peak = _status("VmHWM")
        replay.load_state_dict(state["replay"])
        print(
            f"load {where}: RSS before (buffer allocated) {before:.0f} MiB, peak in load_checkpoint {peak:.0f} MiB "
            f"(+{peak - before:.0f}), {time.monotonic() - started:.1f} s",
            flush=True,
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--capacity", type=int, default=50_000)
    parser.add_argument("--case", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        case(args.case[0], args.case[1], args.capacity)
        return 0
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    moto = subprocess.Popen(
        [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    env = dict(
        os.environ, AWS_ACCESS_KEY_ID="bench", AWS_SECRET_ACCESS_KEY="bench", AWS_DEFAULT_REGION="us-east-1",
        AWS_ENDPOINT_URL=f"http://127.0.0.1:{port}",
    )  # fmt: skip
    try:
        for _ in range(300):
            try:
                socket.create_connection(("127.0.0.1", port), 1).close()
                break
            except OSError:
                time.sleep(0.2)
        subprocess.run([sys.executable, "-c", "import s3fs; s3fs.S3FileSystem().mkdir('bench')"], env=env, check=True)
        with tempfile.TemporaryDirectory() as local:
            for url in (f"{local}/run-1/checkpoint.pt", "s3://bench/run-1/checkpoint.pt"):
                for kind in ("save", "load"):
                    command = [sys.executable, __file__, "--capacity", str(args.capacity), "--case", kind, url]
                    subprocess.run(command, env=env, check=True)
    finally:
        moto.terminate()
        moto.wait(timeout=10)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
