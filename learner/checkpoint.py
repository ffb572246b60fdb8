"""Checkpoints on disk, one file per run, written atomically (a temporary file, fsync, then rename).

Everything in a checkpoint is tensors, numbers, strings, lists and dicts, so it loads with weights_only=True.
"""

import os
from pathlib import Path
from typing import Any

import torch

FILENAME = "checkpoint.pt"


def checkpoint_path(checkpoint_dir: Path, run_id: int) -> Path:
    return Path(checkpoint_dir) / f"run-{run_id}" / FILENAME


def save_checkpoint(path: Path, state: dict[str, Any]) -> int:
    """Write `state` to `path` atomically; returns its size in bytes. A crash leaves the old file intact."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as handle:
            torch.save(state, handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)
    return path.stat().st_size


def load_checkpoint(path: Path) -> dict[str, Any] | None:
    """The saved state, or None when there is no checkpoint yet."""
    if not path.exists():
        return None
    return torch.load(path, map_location="cpu", weights_only=True)
