"""Checkpoints, one per run, at a local path or an fsspec URL (RAQ_CHECKPOINT_URL: s3://bucket/prefix, …).

Writes are atomic, so a reader never sees half a checkpoint, and streamed: torch.save writes straight into the
destination, which holds at most one upload part in memory, never a second copy of the whole checkpoint.

- A local path: a temporary file beside it, fsync, rename, fsync of the directory.
- Object stores (s3, gcs, azure): one PUT, or a multipart upload that becomes visible only when it is completed;
  a failed save aborts the upload and a killed writer leaves an incomplete upload that is never visible.
- Any other fsspec file system: a temporary key, then a move onto the final key.

Reads are streamed too: torch.load reads the zip's records through the open file (ranged GETs on S3).
Everything in a checkpoint is tensors, numbers, strings, lists and dicts, so it loads with weights_only=True.

A write that finds the store full (no space left, or over a quota) raises CheckpointStoreFull, whose message is the
run's failure reason: "checkpoint store full: …". No temporary file is left behind.
"""

import errno
import io
import json
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch

from contract.checkpoint_location import FILENAME, checkpoint_path, checkpoint_url, is_remote
from contract.store.errors import error_chain

__all__ = [
    "FILENAME", "CheckpointStoreFull", "checkpoint_path", "checkpoint_url", "is_remote", "load_checkpoint",
    "save_checkpoint",
]  # fmt: skip

# Object stores whose writes become visible at once and whole when the upload completes.
ATOMIC_UPLOAD_PROTOCOLS = frozenset({"s3", "s3a", "gs", "gcs", "az", "abfs", "abfss", "adl"})
# Upload part size (and read-ahead block) on object stores: the most of a checkpoint held in memory at once.
BLOCK_SIZE = 16 * 1024 * 1024


def _local(location: Path | str) -> Path:
    location = str(location)
    return Path(location.removeprefix("file://"))


STORE_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})


class CheckpointStoreFull(RuntimeError):
    """The checkpoint store has no room for a write: the run cannot go on until someone frees space."""


def _full_store_error(error: BaseException) -> OSError | None:
    """The OSError "no space left" (or "quota exceeded") that `error` is or was raised while handling, if any
    (torch.save reports a failed write as a RuntimeError of its own, with the OSError as its context)."""
    return next(
        (e for e in error_chain(error) if isinstance(e, OSError) and e.errno in STORE_FULL_ERRNOS), None
    )


@contextmanager
def _naming_a_full_store(location: Path | str) -> Iterator[None]:
    try:
        yield
    except Exception as error:
        full = _full_store_error(error)
        if full is None:
            raise
        raise CheckpointStoreFull(f"checkpoint store full: cannot write {location} ({full.strerror})") from error


def save_checkpoint(location: Path | str, state: dict[str, Any]) -> int:
    """Write `state` to `location` atomically; returns its size in bytes. A crash leaves the old one intact; a full
    store raises CheckpointStoreFull."""
    with _naming_a_full_store(location):
        return _save_checkpoint(location, state)


def _save_checkpoint(location: Path | str, state: dict[str, Any]) -> int:
    if not is_remote(location):
        return _save_local(_local(location), state)
    import fsspec  # only a learner with a remote checkpoint URL needs it (pip install '.[objectstore]')

    fs, path = fsspec.core.url_to_fs(str(location))
    protocols = {fs.protocol} if isinstance(fs.protocol, str) else set(fs.protocol)
    if protocols & ATOMIC_UPLOAD_PROTOCOLS:
        _stream(fs.open(path, "wb", block_size=BLOCK_SIZE), state)
    else:
        parent = path.rsplit("/", 1)[0]
        if parent and parent != path:
            fs.makedirs(parent, exist_ok=True)
        tmp = f"{path}.tmp-{uuid.uuid4().hex}"
        try:
            _stream(fs.open(tmp, "wb"), state)
            fs.mv(tmp, path)
        finally:
            if fs.exists(tmp):
                fs.rm(tmp)
    return int(fs.size(path))


class _Blocks(io.RawIOBase):
    """An fsspec file seen through reads and writes of at most BLOCK_SIZE bytes.

    torch.save writes each tensor's bytes in one call and torch.load reads each one in one readinto; handed to an
    fsspec file as they are, a 600 MB replay buffer would be copied whole into its write buffer (and then into
    parts) or fetched whole into its read cache: 3x the checkpoint in memory (measured). In blocks, the file
    holds one or two blocks at a time.
    """

    def __init__(self, handle: Any) -> None:
        super().__init__()
        self.handle = handle

    def readable(self) -> bool:
        return self.handle.readable()

    def writable(self) -> bool:
        return self.handle.writable()

    def seekable(self) -> bool:
        return self.handle.seekable()

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        return self.handle.seek(offset, whence)

    def tell(self) -> int:
        return self.handle.tell()

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        done = 0
        while done < len(view):
            chunk = self.handle.read(min(BLOCK_SIZE, len(view) - done))
            if not chunk:
                break
            view[done : done + len(chunk)] = chunk
            done += len(chunk)
        return done

    def write(self, data: Any) -> int:
        view = memoryview(data).cast("B")
        for start in range(0, len(view), BLOCK_SIZE):
            self.handle.write(view[start : start + BLOCK_SIZE])
        return len(view)


def _stream(handle: Any, state: dict[str, Any]) -> None:
    """torch.save into an open fsspec file; on an error the upload is discarded, never completed."""
    try:
        torch.save(state, _Blocks(handle))
    except BaseException:
        discard = getattr(handle, "discard", None)
        if discard is not None:
            discard()  # S3: aborts the multipart upload; nothing is written
            handle.closed = True  # type: ignore[misc]  (so that its finaliser does not complete the upload)
        raise
    handle.close()


def _save_local(path: Path, state: dict[str, Any]) -> int:
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


def save_json(location: Path | str, value: Any) -> None:
    """Write `value` as JSON to `location` (a path or fsspec URL), atomically where the file system allows; a full
    store raises CheckpointStoreFull."""
    data = json.dumps(value, indent=1).encode()
    with _naming_a_full_store(location):
        if not is_remote(location):
            path = _local(location)
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f"{path.name}.tmp-{uuid.uuid4().hex}")
            try:
                tmp.write_bytes(data)
                os.replace(tmp, path)
            finally:
                tmp.unlink(missing_ok=True)
            return
        import fsspec

        with fsspec.open(str(location), "wb") as handle:  # object stores replace a file whole
            handle.write(data)


def load_json(location: Path | str) -> Any | None:
    """The JSON at `location`, or None when there is none (or it cannot be read)."""
    try:
        if not is_remote(location):
            return json.loads(_local(location).read_bytes())
        import fsspec

        with fsspec.open(str(location), "rb") as handle:
            return json.loads(handle.read())
    except (FileNotFoundError, ValueError):
        return None


def load_checkpoint(location: Path | str) -> dict[str, Any] | None:
    """The saved state, or None when there is no checkpoint yet."""
    if not is_remote(location):
        path = _local(location)
        if not path.exists():
            return None
        return torch.load(path, map_location="cpu", weights_only=True)
    import fsspec

    fs, path = fsspec.core.url_to_fs(str(location))
    fs.invalidate_cache(path)  # another host may have written it since this process last looked
    try:
        handle = fs.open(path, "rb", block_size=BLOCK_SIZE, cache_type="readahead")
    except FileNotFoundError:
        return None
    with handle, _Blocks(handle) as blocks:
        return torch.load(blocks, map_location="cpu", weights_only=True)
