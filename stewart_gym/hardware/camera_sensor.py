"""The camera as ``deploy``'s ball sensor: frames read in a background thread, the newest detection taken.

:class:`CameraSensor` is a :class:`~stewart_gym.sensing.BallSensor`. A thread
grabs frames from a camera (index or device), a named pipe carrying an MJPEG stream
(``virtual-device --camera-stream``), or a video file (played at its own frame
rate, as a camera would deliver it), runs
:func:`~stewart_gym.vision.locate_ball` on each and keeps the newest detection
with its capture time. ``read(t)`` returns the newest *found* ball: a frame with
no ball (or no plate) leaves the last one in place, so its age grows and the
deploy watchdog sends the platform home exactly as for a stale panel reading.
"""

from __future__ import annotations

import os
import stat
import threading
import time

from stewart_gym.errors import DeviceFailure
from stewart_gym.sensing import Reading
from stewart_gym.vision import CameraConfig, Detection, locate_ball

__all__ = ["CameraSensor"]


class CameraSensor:
    """Ball readings from a camera or a video file (see the module's description)."""

    def __init__(self, config: CameraConfig) -> None:
        import cv2

        self.config = config
        source = config.source
        live_pipe = isinstance(source, str) and stat.S_ISFIFO(os.stat(source).st_mode)
        self._is_file = isinstance(source, str) and not source.startswith("/dev/") and not live_pipe
        if live_pipe:  # an MJPEG stream in a named pipe (the virtual device's camera): decode as it comes
            os.environ.setdefault("OPENCV_FFMPEG_CAPTURE_OPTIONS", "probesize;32|analyzeduration;0|fflags;nobuffer|f;mjpeg")
            self._cap = cv2.VideoCapture(source, cv2.CAP_FFMPEG)
        else:
            self._cap = cv2.VideoCapture(source)
        if not self._cap.isOpened():
            raise DeviceFailure(f"camera {source!r} cannot be opened (wrong index or path, or in use?)")
        if not self._is_file:
            width, height = config.resolution
            self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
            self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
            self._cap.set(cv2.CAP_PROP_FPS, config.fps)
        fps = self._cap.get(cv2.CAP_PROP_FPS) if self._is_file else 0.0
        self._period = 1.0 / (fps if fps and fps > 0 else config.fps)
        self._lock = threading.Lock()
        self._latest: tuple[tuple[float, float], float] | None = None
        self.last_detection: Detection | None = None
        self.frames = self.found = 0
        self.ended = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_frame = time.monotonic()
        while not self._stop.is_set():
            ok, frame = self._cap.read()
            captured = time.monotonic()
            if not ok:
                self.ended = True  # end of the video, or the camera went away: readings go stale
                return
            detection = locate_ball(frame, self.config)
            with self._lock:
                self.frames += 1
                self.last_detection = detection
                if detection.xy_mm is not None:
                    self.found += 1
                    self._latest = (detection.xy_mm, captured)
            if self._is_file:  # a file plays at its frame rate, as the camera that recorded it delivered it
                next_frame += self._period
                self._stop.wait(max(0.0, next_frame - time.monotonic()))

    def read(self, t: float) -> Reading | None:
        """The newest ball found ((x, y) m, capture time on the caller's clock ``t``), or None before the first."""
        with self._lock:
            latest = self._latest
        if latest is None:
            return None
        (x_mm, y_mm), captured = latest
        return (x_mm * 1e-3, y_mm * 1e-3), t - (time.monotonic() - captured)

    def close(self) -> None:
        """Stop the thread and release the camera."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._cap.release()
