"""A camera watching the ball: its model for simulation (fast, analytic) and its presets.

Most hobby ball balancers see the ball with a camera. :class:`CameraSpec`
describes one; :class:`SimulatedCamera` is the env's sensor model for it (a
:class:`~stewart_gym.sensing.SimulatedSensor`, like the touch panel). A frame is
exposed every ``1 / fps`` s and its detection is available ``latency_s`` later.
The detection of the ball in a frame is modelled as the vision pipeline
(:mod:`stewart_gym.vision`) produces it:

1. the ball's centre, one radius above the plate, is projected into the image
   by a pinhole camera on the plate's axis (``mount`` above, or below a
   transparent plate, ``distance_m`` from the plate surface);
2. its centroid gets Gaussian noise of ``centroid_noise_px`` and is quantised to
   1/(blob diameter) of a pixel;
3. the pixel is mapped back onto the plane ``assumed_radius_m`` above the plate:
   the ball's radius when the pipeline corrects the parallax (exact, up to a
   radius error), 0 for a flat target: a ball off the camera axis then reads
   farther out by ``r / (distance − r)`` of its offset;
4. a frame misses the ball with probability ``miss_rate``.

Everything else about the timing (sample-and-hold between frames, linear
interpolation of the true path) is as for the touch panel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from stewart_gym.errors import ConfigError
from stewart_gym.sensing import BallHistory

__all__ = ["CAMERA_PRESETS", "CameraSpec", "SimulatedCamera", "camera_height", "camera_preset", "detection"]

#: Frames whose draws (a uniform and two standard normals each) a camera takes from its generator at a time.
FRAME_DRAWS = 64


@dataclass(frozen=True)
class CameraSpec:
    """A camera looking at the plate along its axis.

    Attributes:
        name: a label.
        mount: ``"above"`` the plate, or ``"below"`` a transparent plate.
        distance_m: from the camera to the plate surface at home, m.
        resolution: (width, height) px.
        fov_deg: horizontal field of view, degrees.
        fps: frames per second.
        latency_s: from exposure to the detection being available, s.
        centroid_noise_px: standard deviation of the ball's centroid, px.
        miss_rate: probability that a frame does not find the ball.
        parallax_corrected: True if the pipeline maps the ball onto the plane one
            radius above the plate (it knows the radius); False: onto the plate.
    """

    name: str = "webcam30"
    mount: Literal["above", "below"] = "above"
    distance_m: float = 0.50
    resolution: tuple[int, int] = (640, 480)
    fov_deg: float = 60.0
    fps: float = 30.0
    latency_s: float = 0.060
    centroid_noise_px: float = 0.25
    miss_rate: float = 0.02
    parallax_corrected: bool = True

    def __post_init__(self) -> None:
        w, h = self.resolution
        checks = {
            "mount": self.mount in ("above", "below"),
            "distance_m": math.isfinite(self.distance_m) and 0.05 <= self.distance_m <= 5.0,
            "resolution": int(w) >= 32 and int(h) >= 32,
            "fov_deg": math.isfinite(self.fov_deg) and 10.0 <= self.fov_deg <= 150.0,
            "fps": math.isfinite(self.fps) and 1.0 <= self.fps <= 1000.0,
            "latency_s": math.isfinite(self.latency_s) and 0.0 <= self.latency_s <= 1.0,
            "centroid_noise_px": math.isfinite(self.centroid_noise_px) and 0.0 <= self.centroid_noise_px <= 20.0,
            "miss_rate": math.isfinite(self.miss_rate) and 0.0 <= self.miss_rate < 1.0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(f"camera {self.name!r}: invalid {', '.join(bad)} ({self})")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (pinhole): half the width over tan(half the field of view)."""
        return self.resolution[0] / 2 / math.tan(math.radians(self.fov_deg) / 2)

    def mm_per_px(self) -> float:
        """Size of a pixel on the plate at home, mm."""
        return self.distance_m / self.focal_px * 1e3

    def sees(self, half_extent: tuple[float, float]) -> bool:
        """Whether the whole plate (half sizes, m) fits in the image at home."""
        f = self.focal_px
        w, h = self.resolution
        return half_extent[0] / self.distance_m * f <= w / 2 and half_extent[1] / self.distance_m * f <= h / 2


#: The presets: a Pixy2-like smart camera, a 30 fps USB webcam and a 90 fps global-shutter camera.
CAMERA_PRESETS: dict[str, CameraSpec] = {
    "pixy2": CameraSpec("pixy2", "above", 0.45, (316, 208), 60.0, 60.0, 0.015, 0.35, 0.01),
    "webcam30": CameraSpec("webcam30", "above", 0.50, (640, 480), 60.0, 30.0, 0.060, 0.25, 0.02),
    "global90": CameraSpec("global90", "above", 0.45, (640, 480), 60.0, 90.0, 0.012, 0.15, 0.005),
}


def camera_preset(name: str) -> CameraSpec:
    """One of :data:`CAMERA_PRESETS` by name."""
    try:
        return CAMERA_PRESETS[name]
    except KeyError:
        raise ConfigError(f"camera preset must be one of {sorted(CAMERA_PRESETS)}, got {name!r}") from None


def camera_height(spec: CameraSpec) -> float:
    """m: the camera's height above the plate's surface, on its axis (negative below a transparent plate)."""
    return spec.distance_m if spec.mount == "above" else -spec.distance_m


def detection(x: Any, y: Any, noise_u: Any, noise_v: Any, focal_px: Any, camera_z: Any, radius: Any,
              plane: Any) -> tuple[Any, Any]:  # fmt: skip
    """The pipeline's plate coordinates (m) of balls whose centres are at plate (``x``, ``y``), with centroid noise
    (``noise_u``, ``noise_v``) px: the centre, ``radius`` above the plate, projected by a pinhole camera
    ``camera_z`` above it (focal length ``focal_px``), quantised to 1/(blob diameter) of a pixel, and mapped back
    onto the plane ``plane`` above the plate. Numbers or arrays (one camera per element), the same arithmetic."""
    depth = np.abs(camera_z - radius)
    u, v = focal_px * x / depth + noise_u, focal_px * y / depth + noise_v
    step = 1.0 / np.maximum(1.0, 2 * radius / depth * focal_px)  # centroid resolution: 1 / blob diameter (px)
    u, v = np.round(u / step) * step, np.round(v / step) * step
    scale = np.abs(camera_z - plane) / focal_px
    return u * scale, v * scale


class SimulatedCamera:
    """Camera detections of a simulated ball (a :class:`~stewart_gym.sensing.SimulatedSensor`).

    Args:
        spec: the camera.
        ball_radius: m, the ball's true radius (its centre's height above the plate).
        assumed_radius: m, the radius the pipeline corrects for (default: the true one).
    """

    def __init__(self, spec: CameraSpec, ball_radius: float = 0.0127, assumed_radius: float | None = None,
                 history_s: float = 1.0) -> None:  # fmt: skip
        self.spec = spec
        self.ball_radius = float(ball_radius)
        self.assumed_radius = assumed_radius
        self._history = BallHistory(history_s)
        self._frames: dict[int, tuple[float, float] | None] = {}
        self._rng = np.random.default_rng()
        self._misses, self._noise = np.zeros(0), np.zeros((0, 2))
        self._drawn = 0  # frames of the current block of draws used

    def reset(self, t: float, xy: Sequence[float], rng: np.random.Generator) -> None:
        """Start over at time ``t`` (s) with the ball at rest at ``xy`` (m); frames draw their noise from ``rng``."""
        self._history.clear()
        self._frames.clear()
        self._rng = rng
        self._drawn = len(self._misses)  # the next frame draws a new block
        self._history.append(t - self.spec.latency_s - 2.0 / self.spec.fps - 1.0, xy[0], xy[1], True)
        self.record(t, xy, True)

    def record(self, t: float, xy: Sequence[float], touching: bool) -> None:
        """Record the true plate-frame ball position ``xy`` (m) at time ``t`` (s)."""
        self._history.append(t, xy[0], xy[1], touching)

    def detect(self, x: float, y: float, noise: tuple[float, float] = (0.0, 0.0)) -> tuple[float, float]:
        """The pipeline's plate coordinates (m) of a ball whose centre is at plate ``(x, y)``, with centroid
        noise ``noise`` (px): projection, quantisation, and back-projection onto the assumed plane."""
        s = self.spec
        r = self.ball_radius
        plane = (r if self.assumed_radius is None else self.assumed_radius) if s.parallax_corrected else 0.0
        u, v = detection(x, y, noise[0], noise[1], s.focal_px, camera_height(s), r, plane)
        return float(u), float(v)

    def _draw(self) -> tuple[float, tuple[float, float]]:
        """A new frame's draws: a uniform (the frame misses the ball if it is under ``miss_rate``) and two standard
        normals (the centroid's noise), taken in order from blocks of :data:`FRAME_DRAWS` frames, one generator
        call each, whether the frame uses them or not."""
        if self._drawn == len(self._misses):
            self._misses = self._rng.random(FRAME_DRAWS)
            self._noise = self._rng.standard_normal((FRAME_DRAWS, 2))
            self._drawn = 0
        k = self._drawn
        self._drawn += 1
        return float(self._misses[k]), (float(self._noise[k, 0]), float(self._noise[k, 1]))

    def read(self, t: float) -> tuple[tuple[float, float], float] | None:
        """((x, y) m, exposure time s) of the newest frame available at ``t``; None if it missed the ball or
        the ball was off the plate."""
        s = self.spec
        k = math.floor((t - s.latency_s) * s.fps + 1e-9)
        ts = k / s.fps
        if k not in self._frames:
            x, y, on = self._history.at(ts)
            draw, noise = self._draw()
            if not on or draw < s.miss_rate:
                self._frames[k] = None
            else:
                self._frames[k] = self.detect(x, y, (noise[0] * s.centroid_noise_px, noise[1] * s.centroid_noise_px))
            if len(self._frames) > 256:
                for old in sorted(self._frames)[:128]:
                    del self._frames[old]
        got = self._frames[k]
        return None if got is None else (got, ts)

