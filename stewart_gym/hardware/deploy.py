"""The fixed-rate control loop that drives real servos: sensor → observation → policy → IK → pulses → safety → bytes.

Every tick (default 50 Hz):

1. read the ball sensor (a :class:`~stewart_gym.sensing.BallSensor`: the touch panel on the serial line, or
   the simulated plant's sensor model);
2. build the observation exactly as the environment does (:class:`~stewart_gym.sensing.BallObserver`);
3. run the policy (an ONNX bundle or the PID baseline: numpy + onnxruntime only);
4. map the action through the IK and the calibration (:class:`~stewart_gym.actions.ActionMapper`);
5. pass the pulses through the :class:`~stewart_gym.hardware.safety.SafetyLayer`:
   channel limits always, a per-channel rate limit, and *hold the last safe
   command* when the action is NaN/inf or the pose is unreachable;
6. write the protocol's bytes.

A reading that is NaN, infinite or off the plate (:func:`~stewart_gym.sensing.reading_is_valid`) is no
reading: the last valid one stays in use and ages, exactly as when the sensor sends nothing, and the log marks
the tick ``invalid``. Watchdog: sensor data older than ``watchdog_s`` or a missed deadline moves the platform
home (rate-limited) until fresh data returns; control resumes on the first tick with a fresh valid reading.

Every way a run ends (its duration, Ctrl-C, SIGTERM or SIGHUP raised as
:class:`~stewart_gym.errors.Stopped`, an error, a device failure) drives the servos home at the rate limit
(at most ``home_timeout_s``; a second stop signal does not cut it short), waits until the bytes have left
(``tcdrain``), and, where the board answers (:meth:`~stewart_gym.hardware.serial_controllers.ServoController.monitor`),
asks it which pulses it holds: the summary says "confirmed" only when they are the home pulses. A run that
ended by itself is judged: too many missed deadlines, no usable action, or no fresh valid reading on most
ticks fail it. Every tick is written to a CSV log flushed line by line, so a crash keeps it.
"""

from __future__ import annotations

import csv
import math
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from stewart_gym.actions import ActionMapper
from stewart_gym.envs.targets import Fixed, Target
from stewart_gym.errors import ConfigError, DeviceFailure, PolicyError
from stewart_gym.hardware.safety import SafetyLayer
from stewart_gym.hardware.serial_controllers import BoardRefused, DeviceError, LineController, ServoController
from stewart_gym.sensing import BallObserver, BallSensor, Reading, ball_contact, reading_is_valid

__all__ = ["LOG_PLATE_COLUMNS", "LOG_READING_COLUMNS", "DeployConfig", "DeployLoop", "DeploySummary", "PanelSensor",
           "Plant", "SimulatedPlant", "log_columns"]


def _through_stops(close: Callable[[], object] | None) -> None:
    """``close()`` (if any), called again where a stop signal interrupts it: what closes is not cut short."""
    while close is not None:
        try:
            close()
            return
        except KeyboardInterrupt:
            continue


class LogWriteError(Exception):
    """The run's log could not be written (a full disk, a device gone): the run ends, home, with its summary."""


class Plant(Protocol):
    """What the pulses drive when no real platform does: the simulated plant of a dry run."""

    def apply(self, pulses_us: np.ndarray) -> None:
        """The pulses just sent; advance one control period."""

    def close(self) -> None:
        """Release it."""


class PanelSensor:
    """The touch panel as the Arduino sketch reports it (``B x,y`` in mm): a :class:`~stewart_gym.sensing.BallSensor`."""

    def __init__(self, controller: LineController) -> None:
        self.controller = controller

    def read(self, t: float) -> Reading | None:
        got = self.controller.poll_ball()
        if got is None:
            return None
        (x_mm, y_mm), arrived = got
        return (x_mm * 1e-3, y_mm * 1e-3), t - (time.perf_counter() - arrived)


class SimulatedPlant:
    """The simulated platform, ball and touch panel as the plant of a hardware-in-the-loop dry run.

    It is a :class:`Plant` (the pulses the loop sends to the serial device also
    drive the simulated servos, one control period per tick) and a
    :class:`~stewart_gym.sensing.BallSensor` (the ball as the env's sensor model
    reports it). The env is used through its public parts only: its backend,
    its sensor and the episode's parameters.
    """

    def __init__(self, env_id: str = "StewartBallBalance-v0", seed: int = 0, randomize: bool = True,
                 ball_position: tuple[float, float] | None = None, geometry: Any = "servo-hexapod",
                 backend: str = "auto", twin: Any = None, control_hz: int = 50) -> None:  # fmt: skip
        import gymnasium as gym

        self.env = gym.make(env_id, randomize=randomize and twin is None, geometry=geometry, backend=backend,
                            twin=twin, control_hz=control_hz).unwrapped  # the twin exactly, where there is one
        options = None if ball_position is None else {"ball_position": ball_position, "ball_velocity": (0.0, 0.0)}
        self.env.reset(seed=seed, options=options)
        self.backend = self.env.sim
        self.sensor = self.env.sensor_model
        self._contact = (self.env.plate_half_extent, self.backend.plate_top, self.env.params.ball.radius)
        #: mm, the ball's distance from the plate centre when the plant was closed (None while it runs)
        self.final_error_mm: float | None = None

    def read(self, t: float) -> Reading | None:
        """The newest reading the simulated panel has sent, dated when it arrived (its sample's time plus the
        panel's latency) on the loop's clock: as :class:`PanelSensor` dates a real panel's line, which says nothing
        of when it was sampled. So the loop, its observer and the log see the sensing delay as on the bench, and
        ``sysid`` fits it in the total latency as it does from a real log."""
        sim_t = self.backend.time
        got = self.sensor.read(sim_t)
        if got is None:
            return None
        arrived = min(got[1] + getattr(self.sensor.spec, "latency_s", 0.0), sim_t)
        return got[0], t - (sim_t - arrived)

    def apply(self, pulses_us: np.ndarray) -> None:
        self.backend.command(pulses_us)
        self.backend.step()
        x, y, z = self.backend.ball_position()
        _, touching = ball_contact(x, y, z, *self._contact)
        self.sensor.record(self.backend.time, (x, y), touching)

    def ball_on_plate(self) -> bool:
        """Whether the ball is on the plate (over it, resting on it or just above)."""
        x, y, z = self.backend.ball_position()
        on_plate, _ = ball_contact(x, y, z, *self._contact)
        return bool(on_plate)

    def put_ball_back(self) -> None:
        """The ball back at rest at the plate's centre, as a hand puts it there (its sensor sees it from its next
        sample)."""
        self.backend.place_ball(np.zeros(2), (0.0, 0.0))

    def ball_error_mm(self) -> float:
        """True distance of the ball from the plate centre, mm (for reports); after :meth:`close`, the last one."""
        if self.final_error_mm is not None:
            return self.final_error_mm
        x, y, _ = self.backend.ball_position()
        return float(math.hypot(x, y) * 1e3)

    def close(self) -> None:
        """Record the ball's final distance from the centre (:attr:`final_error_mm`), then close the simulator."""
        if self.final_error_mm is None:
            self.final_error_mm = self.ball_error_mm()
            self.env.close()

#: Default rate limit, µs of pulse width per second per channel: just under the no-load speed of the
#: reference servos (0.17 s/60° at 1600 µs per π rad ≈ 3,137 µs/s), so it never slows a move the servo
#: could make, but stops a jump. At 50 Hz that is 60 µs per tick.
DEFAULT_SLEW_US_PER_S = 3000.0
#: Highest control rate the loop accepts, Hz (hobby servos take a new pulse every 3–20 ms).
MAX_RATE_HZ = 500.0
#: µs: the largest rate limit per tick the loop accepts.
MAX_STEP_US = 1000.0
#: s: the longest drive home a rate limit may need, from either end of a channel's travel.
MAX_HOME_S = 10.0
#: s: how long the home frame is sent again, and the board asked again, where it does not confirm it holds the home
#: pulses (a frame or an answer lost or garbled on the line).
HOME_CONFIRM_S = 3.0
#: A run that misses more than this fraction of its deadlines has failed: the machine cannot keep the rate.
MAX_MISSED_FRACTION = 0.05
#: A run with no fresh valid reading on more than this fraction of its ticks has failed: the sensor did not work.
MAX_STALE_FRACTION = 0.5
#: The log's last columns: the sensor's newest reading this tick as it gave it, valid or not (plate frame, m) and
#: its sample time on the loop's clock (s); empty (nan) when it gave none. ``sysid`` fits a twin from them.
LOG_READING_COLUMNS = ("reading_x_m", "reading_y_m", "reading_t_s")
#: With a sensor that also sees the plate (the camera: ``plate_pose(t)``), the log ends with the newest plate pose
#: as it gave it: its rotation vector (rad) and position (m) in the camera's frame, and its capture time on the
#: loop's clock (s). ``sysid`` fits each servo's trim from them.
LOG_PLATE_COLUMNS = ("plate_rx_rad", "plate_ry_rad", "plate_rz_rad", "plate_x_m", "plate_y_m", "plate_z_m",
                     "plate_t_s")  # fmt: skip
#: Per-tick flags, in the log's columns and the summary's counts.
TICK_FLAGS = ("held", "clamped", "rate_limited", "homing", "stale", "invalid", "unreachable")


@dataclass
class DeployConfig:
    """Loop settings; checked on creation (:class:`~stewart_gym.errors.ConfigError` names the bad one)."""

    rate_hz: float = 50.0
    duration_s: float | None = None  # None: until Ctrl-C
    watchdog_s: float = 0.100  # sensor data older than this → home
    max_step_us: float = 60.0  # rate limit per channel per tick (DEFAULT_SLEW_US_PER_S at 50 Hz)
    log_path: str | None = "deploy_log.csv"
    home_timeout_s: float = 2.0  # longest drive home at shutdown

    def __post_init__(self) -> None:
        checks = [("rate_hz", self.rate_hz, 0.0, MAX_RATE_HZ), ("watchdog_s", self.watchdog_s, 0.0, 60.0),
                  ("max_step_us", self.max_step_us, 0.0, MAX_STEP_US), ("home_timeout_s", self.home_timeout_s, 0.0, 60.0)]
        if self.duration_s is not None:
            checks.append(("duration_s", self.duration_s, 0.0, math.inf))
        for name, value, lo, hi in checks:
            if not (isinstance(value, (int, float)) and math.isfinite(value) and lo < value <= hi):
                raise ConfigError(f"deploy: {name} must be a finite number in ({lo:g}, {hi:g}], got {value!r}")


@dataclass
class DeploySummary:
    """What happened; ``exit_code`` 0 clean stop, 1 failed run or error, 2 device failure, 128 + N stopped by signal N.

    ``home`` says how the run left the servos: ``"confirmed"`` (the board reports the home pulses),
    ``"sent"`` (the home frame left the computer; the board cannot confirm), ``"not confirmed"`` (sent, but the
    board did not answer or reports other pulses) or ``"not sent"`` (the port failed first), with the reason
    in ``home_note``.
    """

    ticks: int = 0
    frames_sent: int = 0
    duration_s: float = 0.0
    held: int = 0
    clamped: int = 0
    rate_limited: int = 0
    homing: int = 0
    stale: int = 0
    invalid: int = 0
    missed_deadlines: int = 0
    unreachable: int = 0
    jitter_ms_mean: float = 0.0
    jitter_ms_max: float = 0.0
    compute_ms_p99: float = 0.0
    home: str = "not sent"
    home_note: str = ""
    board_answers: int | None = None
    board_wait_ms_max: float = 0.0
    exit_code: int = 0
    message: str = "completed"
    #: the tick at which the sensor's source ended (a camera's video ran out), and why; None if it did not
    source_ended_tick: int | None = None
    source_ended: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def homed(self) -> bool:
        """The home frame reached the board (confirmed) or at least left the computer (sent)."""
        return self.home in ("confirmed", "sent")

    def home_text(self) -> str:
        """One phrase for how the servos were left."""
        text = {"confirmed": "servos homed: confirmed by the board", "sent": "home frame sent, not confirmed",
                "not confirmed": "servos NOT confirmed home", "not sent": "servos NOT homed"}[self.home]  # fmt: skip
        return f"{text} ({self.home_note})" if self.home_note else text

    def text(self) -> str:
        board = ("" if self.board_answers is None else
                 f"board answered {self.board_answers} questions, longest wait {self.board_wait_ms_max:.0f} ms; ")
        ended = ("" if self.source_ended_tick is None else
                 f"the sensor's source ended at tick {self.source_ended_tick} ({self.source_ended}): no fresh reading "
                 "after it; ")  # fmt: skip
        return (f"{self.message}: {self.ticks} ticks in {self.duration_s:.2f} s, {self.frames_sent} frames sent; "
                f"held {self.held}, clamped {self.clamped}, rate-limited {self.rate_limited}, homing {self.homing}, "
                f"stale sensor {self.stale}, invalid readings {self.invalid}, missed deadlines {self.missed_deadlines}, "
                f"unreachable {self.unreachable}; jitter mean {self.jitter_ms_mean:.2f} ms, max "
                f"{self.jitter_ms_max:.2f} ms; compute p99 {self.compute_ms_p99:.3f} ms; "
                f"{ended}{board}{self.home_text()}")  # fmt: skip


def log_columns(obs_size: int, action_size: int, plate: bool = False) -> list[str]:
    """The deploy log's header: the tick's time and jitter, the observation, the action, the pose asked for, the
    pulses sent, the tick's flags, whether it missed its deadline, the bytes written, the reading, and with
    ``plate`` the plate pose the sensor saw (:data:`LOG_PLATE_COLUMNS`)."""
    return ["t_s", "jitter_ms", *(f"obs{i}" for i in range(obs_size)), *(f"action{i}" for i in range(action_size)),
            "x_m", "y_m", "z_m", "roll", "pitch", "yaw", *(f"pulse{i}_us" for i in range(6)), *TICK_FLAGS,
            "missed_deadline", "bytes", *LOG_READING_COLUMNS, *(LOG_PLATE_COLUMNS if plate else ())]  # fmt: skip


class DeployLoop:
    """Runs a policy on servos at a fixed rate. See the module docstring for the tick."""

    def __init__(self, policy: Any, mapper: ActionMapper, controller: ServoController, sensor: BallSensor,
                 config: DeployConfig | None = None, target: Target | None = None,
                 plant: Plant | None = None) -> None:  # fmt: skip
        self.policy, self.mapper, self.controller, self.sensor = policy, mapper, controller, sensor
        self.plant = plant
        self.config = config or DeployConfig()
        self.target = target or Fixed()
        self.safety = SafetyLayer(mapper.calibration, self.config.max_step_us)
        width, depth = mapper.geometry.plate_extent
        self.observer = BallObserver(mapper.size, plate_half=(width / 2, depth / 2),
                                     estimator=getattr(policy, "estimator", "lowpass"),  # the policy's own
                                     integral=getattr(policy, "integral", False))  # fmt: skip
        sizes = (getattr(policy, "obs_size", self.observer.builder.size), getattr(policy, "action_size", mapper.size))
        if sizes != (self.observer.builder.size, mapper.size):
            raise PolicyError(f"the policy reads {sizes[0]} observation values and gives {sizes[1]} actions, but "
                              f"{mapper.mode!r} mode needs {self.observer.builder.size} and {mapper.size}")  # fmt: skip
        self.plate_half = (width / 2, depth / 2)
        self.prev_action: tuple[float, ...] = (0.0,) * mapper.size
        self.roll_pitch = (0.0, 0.0)
        self._observing = False  # the observer starts from the first reading, as the env's does at reset
        self._last_valid: Reading | None = None  # the newest reading that could be a ball on the plate

    def checked(self, got: Reading | None, t: float) -> tuple[tuple[tuple[float, float], float] | None, bool]:
        """The sensor's newest reading at ``t`` → ((x, y), age s) to use and whether the newest was invalid.

        An invalid reading (:func:`~stewart_gym.sensing.reading_is_valid`, or one dated in the future) is no
        reading: the last valid one is used instead, and ages, as when the sensor sends nothing."""
        invalid = got is not None and not (reading_is_valid(got, self.plate_half) and got[1] <= t + 1e-3)
        if got is not None and not invalid:
            self._last_valid = got
        use = self._last_valid if invalid else got
        return (None if use is None else (use[0], t - use[1])), invalid

    # --------------------------------------------------------------- one tick
    def compute(self, reading: tuple[tuple[float, float], float] | None, t: float) -> tuple[np.ndarray, np.ndarray,
                                                                                           np.ndarray, dict]:  # fmt: skip
        """Observation → policy → IK → safety for one tick; returns (obs, action, pulses, flags). No I/O."""
        target_xy, target_vel = self.target(t)
        sample = None if reading is None else (reading[0], t - reading[1])
        if sample is not None and not self._observing:
            self.observer.reset(sample[1], sample[0])
            self._observing = True
        obs = self.observer.observe(sample, target_xy, target_vel, self.roll_pitch, self.prev_action, now=t)
        if not np.all(np.isfinite(obs)):  # never expected (readings are checked): start the observer afresh
            self._observing = False
        flags = {"stale": reading is None or reading[1] > self.config.watchdog_s, "unreachable": False}
        action = np.full(self.mapper.size, np.nan)
        usable = False
        mapped = None
        try:
            action = np.asarray(self.policy(obs), dtype=np.float64).reshape(self.mapper.size)
            if np.all(np.isfinite(action)):
                mapped = self.mapper(action)
                flags["unreachable"] = mapped.scaled
                usable = not mapped.scaled
        except (ValueError, FloatingPointError):
            mapped = None
        requested = mapped.pulses if mapped is not None else None
        pose = mapped.pose if mapped is not None else np.full(6, np.nan)  # NaN in "pulse" mode too
        res = self.safety.toward_home() if flags["stale"] else self.safety.filter(requested if usable else None,
                                                                                  usable)  # fmt: skip
        if usable and not flags["stale"] and not res.held:
            assert mapped is not None
            self.prev_action = mapped.action  # the action as applied, clipped to [-1, 1]
            if self.mapper.mode != "pulse":
                self.roll_pitch = (float(pose[3]), float(pose[4]))
        flags.update(held=res.held, clamped=res.clamped, rate_limited=res.rate_limited, homing=res.homing)
        return obs, action, res.pulses, {**flags, "pose": pose}

    # ------------------------------------------------------------------ loop
    def run(self) -> DeploySummary:
        cfg = self.config
        period = 1.0 / cfg.rate_hz
        summary = DeploySummary()
        if self.controller.monitoring:
            summary.board_answers = 0
        sees_plate = callable(getattr(self.sensor, "plate_pose", None))
        try:
            writer, fh = self._open_log(sees_plate)
        except OSError as exc:
            self._close(None)
            raise ConfigError(f"the log {cfg.log_path} cannot be written ({exc.strerror or exc}); nothing was "
                              "moved") from None
        jitters, computes = [], []
        port_failed = False  # whether the port or the board failed (the sensor failing leaves the board to ask)
        start = time.perf_counter()  # (the finest monotonic clock everywhere: time.monotonic ticks every 15.6 ms on
        # Windows before Python 3.13; the controllers and the camera date what they read on the same clock)
        next_tick = start
        missed = False
        try:
            while cfg.duration_s is None or summary.ticks < round(cfg.duration_s * cfg.rate_hz):
                now = time.perf_counter()
                jitter = (now - next_tick) * 1e3
                t = now - start
                got = self.sensor.read(t)
                ended = getattr(self.sensor, "ended", None)  # a source that can run out (a camera's video)
                if isinstance(ended, str) and summary.source_ended_tick is None:
                    summary.source_ended_tick, summary.source_ended = summary.ticks, ended
                reading, invalid = self.checked(got, t)  # (x, y), age
                c0 = time.perf_counter()
                obs, action, pulses, flags = self.compute(reading, t)
                flags["invalid"] = invalid
                if missed:  # the last tick overran: go home this tick
                    pulses = self.safety.toward_home().pulses
                    flags["homing"] = True
                data = self.controller.send(pulses)
                computes.append((time.perf_counter() - c0) * 1e3)
                if self.plant is not None:
                    self.plant.apply(pulses)
                summary.ticks += 1
                for key in TICK_FLAGS:
                    setattr(summary, key, getattr(summary, key) + int(bool(flags[key])))
                jitters.append(jitter)
                if writer is not None:
                    bits = [int(bool(flags[k])) for k in TICK_FLAGS]
                    raw = (math.nan,) * 3 if got is None else (*got[0], got[1])  # what the sensor gave, as it gave it
                    if sees_plate:
                        plate = self.sensor.plate_pose(t)
                        raw += (math.nan,) * 7 if plate is None else (*plate[0], plate[1])
                    try:
                        writer.writerow([f"{t:.4f}", f"{jitter:.3f}", *np.round(obs, 5), *np.round(action, 5),
                                         *np.round(flags["pose"], 6), *np.round(pulses, 2), *bits, int(missed),
                                         len(data), *(f"{v:.6f}" for v in raw)])  # fmt: skip
                        fh.flush()
                    except OSError as exc:
                        raise LogWriteError(f"the log {cfg.log_path} cannot be written ({exc.strerror or exc})") from None
                next_tick += period
                sleep = next_tick - time.perf_counter()
                missed = sleep < -period  # more than a whole period late
                if missed:
                    summary.missed_deadlines += 1
                    next_tick = time.perf_counter()
                elif sleep > 0:
                    self.controller.wait_until(next_tick)  # a panel's lines are read (and dated) as they arrive
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM/SIGHUP raised as errors.Stopped
            summary.message = f"stopped by {getattr(exc, 'name', 'Ctrl-C (SIGINT)')}"
            summary.exit_code = 128 + int(getattr(exc, "signum", signal.SIGINT))
        except DeviceFailure as exc:  # the port, the board, or the sensor (a camera lost mid-run)
            summary.message, summary.exit_code = f"device failure: {exc}", 2
            port_failed = isinstance(exc, DeviceError) and not isinstance(exc, BoardRefused)  # (it still answers)
        except LogWriteError as exc:
            summary.message, summary.exit_code = f"error: {exc}", 1
        except Exception as exc:  # noqa: BLE001  (anything: go home, keep the log, report)
            summary.message, summary.exit_code = f"error: {type(exc).__name__}: {exc}", 1
        finally:
            self._go_home(period, summary, port_failed)
            self._close(fh, summary)
        summary.duration_s = time.perf_counter() - start
        summary.frames_sent = self.controller.frames_sent
        if summary.board_answers is not None:
            summary.board_answers = self.controller.answers
            summary.board_wait_ms_max = self.controller.longest_wait_s * 1e3
        if jitters:
            summary.jitter_ms_mean = float(np.mean(np.abs(jitters)))
            summary.jitter_ms_max = float(np.max(np.abs(jitters)))
            summary.compute_ms_p99 = float(np.percentile(computes, 99))
        if summary.message == "completed" and summary.ticks:  # a run that ended by itself is judged
            self._judge(summary)
        if summary.exit_code == 0 and not summary.homed:  # the end was clean, the way home was not
            summary.message += "; device failure on the way home"
            summary.exit_code = 2
        return summary

    def _judge(self, summary: DeploySummary) -> None:
        cfg = self.config
        if summary.missed_deadlines > MAX_MISSED_FRACTION * summary.ticks:
            summary.message = (f"failed: missed {summary.missed_deadlines} of {summary.ticks} deadlines; this "
                               f"machine cannot keep {cfg.rate_hz:g} Hz (lower --rate)")  # fmt: skip
            summary.exit_code = 1
        elif summary.stale > MAX_STALE_FRACTION * summary.ticks:
            summary.message = (f"failed: no fresh valid reading on {summary.stale} of {summary.ticks} ticks "
                               f"({summary.invalid} invalid: NaN, infinite or off the plate); the platform was held "
                               "home meanwhile: check the sensor")  # fmt: skip
            summary.exit_code = 1
        elif summary.held == summary.ticks:
            summary.message = "failed: the policy gave no usable action on any tick (every tick held the pose)"
            summary.exit_code = 1

    def _go_home(self, period: float, summary: DeploySummary, port_failed: bool = False) -> None:
        """Drive home at the rate limit (at most ``home_timeout_s``; a stop signal meanwhile does not cut it
        short), drain the port, and ask the board what it holds. Sets ``summary.home`` and ``home_note``. After
        the port or the board failed (``port_failed``), the home frames are tried all the same, without asking the
        board anything."""
        deadline = time.perf_counter() + self.config.home_timeout_s
        self.controller.fail_on_refusals = False  # the board's answer says whether the servos got home
        failed = port_failed
        if failed:
            self.controller.monitoring = False
        reached = False
        while not reached:
            try:
                while time.perf_counter() < deadline:
                    self.controller.send(self.safety.toward_home().pulses)
                    if self.safety.at_home():
                        reached = True
                        break
                    time.sleep(period)
                break
            except KeyboardInterrupt:  # a second stop signal: the drive home goes on, bounded by its deadline
                continue
            except DeviceError as exc:
                summary.home, summary.home_note = "not sent", "the port failed" if failed else str(exc)
                return
        if not reached:
            summary.home = "not sent"
            summary.home_note = f"the drive home took longer than {self.config.home_timeout_s:g} s"
            return
        try:
            self.controller.drain()
            if failed:
                summary.home, summary.home_note = "not confirmed", "home frames written after the device failure"
                return
            if not self.controller.monitoring:
                summary.home, summary.home_note = "sent", "the board's answers are not read (--write-only)"
                return
            confirmed, held = self.controller.confirm(self.safety.home, self.controller.answer_timeout_s)
            resent, until = 0, time.perf_counter() + HOME_CONFIRM_S
            while not confirmed and time.perf_counter() < until:  # a frame lost or garbled on the line: send it again
                self.controller.send(self.safety.toward_home().pulses)  # (at home: the home pulses)
                self.controller.drain()
                resent += 1
                got, answer = self.controller.confirm(self.safety.home, self.controller.answer_timeout_s, attempts=1)
                confirmed, held = got, answer if answer is not None else held
            if confirmed and resent:
                summary.home_note = f"after sending the home frame {resent} more time(s)"
        except DeviceError as exc:
            summary.home, summary.home_note = "not confirmed", str(exc)
            return
        except KeyboardInterrupt:
            summary.home, summary.home_note = "sent", "interrupted while asking the board"
            return
        if confirmed:
            summary.home = "confirmed"
        elif held is None:
            summary.home, summary.home_note = "not confirmed", "the board did not answer"
        else:
            summary.home = "not confirmed"
            summary.home_note = (f"the board holds {np.round(held, 1).tolist()} µs, not the home pulses "
                                 f"{np.round(self.safety.home, 1).tolist()}")  # fmt: skip

    def _close(self, log: Any, summary: DeploySummary | None = None) -> None:
        """Close the port, the log, the plant and the sensor; a stop signal meanwhile does not cut this short, and a
        log that cannot be written (a full disk) is said in ``summary``."""
        _through_stops(self.controller.close)
        try:
            _through_stops(getattr(log, "close", None))
        except OSError as exc:
            if summary is not None and "cannot be written" not in summary.message:
                note = f"the log {self.config.log_path} cannot be written ({exc.strerror or exc})"
                summary.message = f"error: {note}" if summary.exit_code == 0 else f"{summary.message}; {note}"
                summary.exit_code = summary.exit_code or 1
        for part in (self.plant, self.sensor):
            _through_stops(getattr(part, "close", None))

    def _open_log(self, plate: bool) -> tuple[Any, Any]:
        if not self.config.log_path:
            return None, None
        path = Path(self.config.log_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = path.open("w", newline="", buffering=1)
        writer = csv.writer(fh)
        writer.writerow(log_columns(self.observer.builder.size, self.mapper.size, plate))
        fh.flush()
        return writer, fh
