"""The camera as ``deploy``'s ball sensor: frames read in a background thread, the newest detection taken.

:class:`CameraSensor` is a :class:`~stewart_gym.sensing.BallSensor`. A thread
opens the source (a camera index or device, a named pipe carrying an MJPEG stream
from ``virtual-device --camera-stream``, or a video file played at its own frame
rate, as a camera would deliver it: a raw MJPEG file, which stores none, at the
config's ``fps``), runs :func:`~stewart_gym.vision.locate_ball`
on each frame and keeps the newest detection with its capture time. The
constructor waits for the first frame: a source that delivers none within
``first_frame_timeout_s`` (a pipe nobody writes to, a camera that hangs) is a
:class:`~stewart_gym.errors.DeviceFailure` before anything moves; a source that is a
folder, or a file that is no video, a :class:`~stewart_gym.errors.ConfigError`.

``read(t)`` returns the newest *found* ball: a frame with no ball, no plate, or a
position that cannot be a ball on the plate (:func:`~stewart_gym.sensing.reading_is_valid`)
leaves the last one in place, so its age grows and the deploy watchdog sends the
platform home exactly as for a stale panel reading.
"""

from __future__ import annotations

import os
import stat
import threading
import time
from collections.abc import Sequence
from pathlib import Path

from stewart_gym.errors import ConfigError, DeviceFailure
from stewart_gym.sensing import Reading, reading_is_valid
from stewart_gym.vision import CameraConfig, Detection, locate_ball, open_capture, source_problem

__all__ = ["FIRST_FRAME_TIMEOUT_S", "LIVE_PIPE_OPTIONS", "RAW_MJPEG_SUFFIXES", "CameraSensor"]

#: s: the longest the sensor waits for the source's first frame.
FIRST_FRAME_TIMEOUT_S = 5.0
#: FFmpeg's options for an MJPEG stream in a named pipe (``OPENCV_FFMPEG_CAPTURE_OPTIONS``, where the user has not
#: set it): decode each frame as it comes, with no read-ahead buffer, so that a reader slower than the stream gets
#: recent frames (FFmpeg's buffer alone would hold seconds of them).
LIVE_PIPE_OPTIONS = "probesize;32|analyzeduration;0|fflags;nobuffer|f;mjpeg"
#: The suffixes of a raw MJPEG file: JPEG frames one after another, with no frame rate stored.
RAW_MJPEG_SUFFIXES = (".mjpg", ".mjpeg")


class CameraSensor:
    """Ball readings from a camera or a video file (see the module's description).

    Args:
        config: the camera config.
        plate_half: (h_x, h_y) m, half the plate's size: a position further out (plus the margin of
            :func:`~stewart_gym.sensing.reading_is_valid`) is no reading. None: not checked here.
        first_frame_timeout_s: the longest wait for the first frame.
    """

    def __init__(self, config: CameraConfig, plate_half: Sequence[float] | None = None,
                 first_frame_timeout_s: float = FIRST_FRAME_TIMEOUT_S) -> None:  # fmt: skip
        self.config = config
        source = config.source
        self._live_pipe = isinstance(source, str) and stat.S_ISFIFO(os.stat(source).st_mode)
        self._is_file = isinstance(source, str) and not source.startswith("/dev/") and not self._live_pipe
        #: whether the source is a raw MJPEG file (.mjpg, .mjpeg), which stores no frame rate (OpenCV would say 25):
        #: it plays at the config's ``fps``
        self.raw_mjpeg = self._is_file and Path(source).suffix.lower() in RAW_MJPEG_SUFFIXES
        self._plate_half = None if plate_half is None else (float(plate_half[0]), float(plate_half[1]))
        self._lock = threading.Lock()
        self._latest: tuple[tuple[float, float], float] | None = None
        self._plate: tuple[tuple[float, ...], float] | None = None  # the newest plate pose and its capture time
        self.last_detection: Detection | None = None
        self.frames = self.found = self.invalid = 0
        #: why no frame comes any more (a video's end, a camera or stream lost), or None while frames come
        self.ended: str | None = None
        self._cap = None
        self._opened = threading.Event()  # the first frame came, or opening failed
        self._failure: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera", daemon=True)
        self._thread.start()
        if not self._opened.wait(first_frame_timeout_s):
            self.close()
            raise DeviceFailure(f"camera {source!r} delivered no frame within {first_frame_timeout_s:g} s (nothing "
                                "writing to the pipe? a camera in use or hung?); nothing was moved")  # fmt: skip
        if self._failure is not None:
            self.close()
            problem = source_problem(source) if not self._live_pipe else None
            if problem is not None:  # a folder, or a file that is no video: the config's to fix
                raise ConfigError(problem)
            raise DeviceFailure(self._failure)

    def _open(self) -> object:
        import cv2

        source = self.config.source
        if self._live_pipe:  # an MJPEG stream in a named pipe (the virtual device's camera): decode as it comes
            os.environ.setdefault("OPENCV_FFMPEG_CAPTURE_OPTIONS", LIVE_PIPE_OPTIONS)
            cap = open_capture(source, cv2.CAP_FFMPEG)
        else:
            cap = open_capture(source)
        if cap.isOpened() and not self._is_file:
            width, height = self.config.resolution
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
            cap.set(cv2.CAP_PROP_FPS, self.config.fps)
        return cap

    def _run(self) -> None:
        import cv2

        cap = self._cap = self._open()  # type: ignore[assignment]
        if self._stop.is_set():
            cap.release()
            return
        if not cap.isOpened():
            self._failure = f"camera {self.config.source!r} cannot be opened (wrong index or path, or in use?)"
            self._opened.set()
            return
        fps = cap.get(cv2.CAP_PROP_FPS) if self._is_file and not self.raw_mjpeg else 0.0
        period = 1.0 / (fps if fps and fps > 0 else self.config.fps)
        next_frame = time.perf_counter()
        while not self._stop.is_set():
            ok, frame = cap.read()
            captured = time.perf_counter()
            if not ok:
                self.ended = ("the video ran out" if self._is_file else  # readings go stale from here
                              "the camera stopped delivering frames (unplugged, or its stream ended)")  # fmt: skip
                if not self._opened.is_set():
                    self._failure = f"camera {self.config.source!r} gave no frame (an empty video, or a dead stream)"
                    self._opened.set()
                return
            detection = locate_ball(frame, self.config)
            with self._lock:
                self.frames += 1
                self.last_detection = detection
                if detection.plate_pose is not None:
                    self._plate = (detection.plate_pose, captured)
                if detection.xy_mm is not None:
                    self.found += 1
                    reading = ((detection.xy_mm[0] * 1e-3, detection.xy_mm[1] * 1e-3), captured)
                    if self._plate_half is None or reading_is_valid(reading, self._plate_half):
                        self._latest = (detection.xy_mm, captured)
                    else:
                        self.invalid += 1
            self._opened.set()
            if self._is_file:  # a file plays at its frame rate, as the camera that recorded it delivered it
                next_frame += period
                self._stop.wait(max(0.0, next_frame - time.perf_counter()))

    def read(self, t: float) -> Reading | None:
        """The newest ball found ((x, y) m, capture time on the caller's clock ``t``), or None before the first. A
        live camera or stream that has stopped delivering frames is a :class:`~stewart_gym.errors.DeviceFailure`
        (a video that has run out is not: its last reading ages, and :attr:`ended` says why)."""
        if self.ended is not None and not self._is_file:
            raise DeviceFailure(f"camera {self.config.source!r}: {self.ended}")
        with self._lock:
            latest = self._latest
        if latest is None:
            return None
        (x_mm, y_mm), captured = latest
        return (x_mm * 1e-3, y_mm * 1e-3), t - (time.perf_counter() - captured)

    def plate_pose(self, t: float) -> tuple[tuple[float, ...], float] | None:
        """The newest plate pose seen (:attr:`Detection.plate_pose <stewart_gym.vision.Detection.plate_pose>`: six
        numbers) and its capture time on the caller's clock ``t``, or None before the first."""
        with self._lock:
            plate = self._plate
        if plate is None:
            return None
        pose, captured = plate
        return pose, t - (time.perf_counter() - captured)

    def close(self) -> None:
        """Stop the thread and release the camera. A thread still blocked opening a named pipe that no writer
        opened is let go: the pipe is opened for writing once, which lets its open return."""
        self._stop.set()
        if self._live_pipe and self._thread.is_alive() and self._cap is None:
            try:
                os.close(os.open(self.config.source, os.O_WRONLY | os.O_NONBLOCK))  # type: ignore[arg-type]
            except OSError:
                pass
        self._thread.join(timeout=2.0)
        if self._cap is not None and not self._thread.is_alive():
            self._cap.release()
