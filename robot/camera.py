"""A camera over OpenCV's `cv2.VideoCapture`: a device index (0 for the first camera), a device path
(/dev/video2), a stream URL (rtsp://…) or a video file (for tests and replays). A video file plays in a loop, starting
again after its last frame, unless `loop=False`; a camera or a stream never loops.

    with OpenCVCamera(0, width=640, height=480) as camera:
        frame = camera.read()  # (480, 640, 3) uint8 RGB
"""

import errno
import threading
from pathlib import Path

import cv2
import numpy as np

from robot.base import CameraBusy


class CameraError(RuntimeError):
    """The camera could not be opened, or gave no frame."""


class OpenCVCamera:
    def __init__(self, source: int | str, *, width: int | None = None, height: int | None = None,
                 loop: bool | None = None) -> None:  # fmt: skip
        """`loop`: start again at the end; None (the default): for a video file, not for a camera or a stream."""
        self.source = source
        self.loop = loop if loop is not None else isinstance(source, str) and Path(source).is_file()
        self._lock = threading.Lock()  # the actor reads frames while the page's live view may read one too
        self.capture = cv2.VideoCapture(source)
        if not self.capture.isOpened():
            device = Path(f"/dev/video{source}" if isinstance(source, int) else source)
            if str(device).startswith("/dev/") and device.exists():  # there, but not ours: another process has it
                raise CameraBusy(errno.EBUSY, f"camera {source!r} is open in another process")
            raise CameraError(f"cannot open camera {source!r}")
        if width:
            self.capture.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        if height:
            self.capture.set(cv2.CAP_PROP_FRAME_HEIGHT, height)

    def read(self) -> np.ndarray:
        """The next frame as (height, width, 3) uint8 RGB."""
        with self._lock:
            ok, frame = self.capture.read()
            if not ok and self.loop:
                self.capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
                ok, frame = self.capture.read()
        if not ok or frame is None:
            raise CameraError(f"camera {self.source!r} gave no frame")
        if frame.ndim == 2:
            return cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
        return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        with self._lock:
            self.capture.release()

    def __enter__(self) -> "OpenCVCamera":
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
