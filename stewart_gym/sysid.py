"""System identification: fit a platform's twin (:mod:`stewart_gym.sim.twin`) from its deploy logs.

The logs hold every pulse sent and every ball reading received, with their times (``identify``'s, or any deploy
run's). The fit replays the logged pulses through the batched simulator
(:class:`~stewart_gym.sim.BatchedSim`) and compares the simulated ball with the readings, over many short
windows at once.

**What it fits, and how.**

- *Servo speed and dead band*: a grid of candidate servos, every window simulated for every candidate in one
  batched run.
- *Total latency* (sensor + servo): a delay of the input is a delay of the output, so each simulated path is
  compared with the readings shifted by each candidate latency (1 ms steps) without simulating again.
- *Each window's start*: the ball's position and velocity at a window's start are not known; they are fitted
  by linear least squares for every candidate, so that they cost nothing and bias nothing. The whole fit runs
  twice: the second time, each window's ball starts where the first fit put it, so that the plate's rotation
  acts on the ball as it moved.
- *The plate's tilt offset* (what the servo trims do to the ball): one constant acceleration of the ball in the
  plate frame, fitted by linear least squares over all windows together. The twin's trims are the smallest six
  that tilt the plate that much.
- *The reading noise*: the spread of the readings around the best fit, less the scatter a moving ball's readings
  get from their uneven age (:attr:`FlightLog.read_time_var_s2`).

The best candidate is refined between grid points by a parabola through its neighbours. The uncertainties come
from a bootstrap over windows (the fit repeated on windows drawn with replacement); they measure the scatter
of the fit, not what the model leaves out.

- *Each servo's trim*, where the logs hold the plate poses a camera saw (``identify --sensor camera``): the
  pulses replayed, and the plate poses they give fitted to the camera's, with the camera's own pose
  (:mod:`stewart_gym.plate_trims`). The replay's servos are whichever of the grid's speeds and dead bands, and of
  speeds :data:`FINE_SPEED_STEPS` times finer around the ball's best, the plate poses fit best, starting from the
  ball's best: with a dead band, a servo stops short of its target, which a trim would take up, and a replay a
  few per cent too slow or too fast moves the trims by several µs. The plate shows the servos more directly than
  the ball does, so the twin takes the plate's choice, with the ball's best latency for the grid's nearest
  speed; their uncertainty is half the grid's spacing (the bootstrap then gives the latency's and the noise's
  only).

**What the ball alone cannot show** is listed as undetermined: the split of the latency between the sensor and
the servos (the twin keeps the sensor's nominal 10 ms and puts the rest on the servos; either way the ball
answers a pulse as late), each servo's own trim (only the tilt they make together), the ball's mass, radius and
rolling friction, the plate's friction and load. A servo speed or dead band at the edge of its grid, or whose
bootstrap spread covers much of the grid, is undetermined too: the logs never asked the servos for it.

**Held out.** The last part of each log (``holdout``) is not fitted. There, the nominal and the fitted twin each
predict the ball's path from the readings of the window's first 0.6 s; the report gives the RMS error of each
over the next 0.5 s and 1 s.
"""

from __future__ import annotations

import csv
import hashlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.blas import one_blas_thread
from stewart_gym.calibration import ServoCalibration
from stewart_gym.envs.randomization import EpisodeParams
from stewart_gym.errors import ConfigError
from stewart_gym.hardware.deploy import LOG_PLATE_COLUMNS, LOG_READING_COLUMNS, log_columns
from stewart_gym.plate_trims import MIN_FRAMES, PlateLog, TrimFit, fit_trims, usable_frames
from stewart_gym.sensing import TouchPanelSpec
from stewart_gym.sim import BallSpec, BatchedSim, ServoSpec
from stewart_gym.sim.twin import TWIN_FIELDS, Twin

__all__ = ["PANEL_PERIOD_S", "READ_OVERHEAD_S", "READ_TIME_VAR_S2", "TICK_DATED_OVERHEAD_S", "TICK_DATED_VAR_S2",
           "FitResult", "FlightLog", "MIN_FIT_WINDOWS", "MIN_POSE_AGREEMENT", "POSE_COLUMNS", "fit_twin",
           "REPORT_FILES", "pose_agreement", "read_log", "twin_ball", "unfit_reason", "write_report"]

#: s: the panel's sample period (the sketch reports at 100 Hz).
PANEL_PERIOD_S = 0.010
#: s: how much older a panel reading is than its stated latency when it arrives: the sketch sends each sample as
#: soon as the panel has it, and the loop reads each line as it arrives (``deploy``'s wait between ticks), so
#: what is left is the time to send and read it. The fitted total latency less this is the twin's.
READ_OVERHEAD_S = 0.001
#: s²: the variance of that age (about ±1 ms): a moving ball's readings scatter by its speed times this much more
#: than the panel's own noise, which the noise estimate takes out.
READ_TIME_VAR_S2 = 0.002**2 / 12
#: s and s²: the extra age, on average, and its variance, of readings in a log dated at the tick that read them,
#: not when they arrived (:attr:`FlightLog.dated_at_ticks`: the loop read the port only at its ticks): the
#: newest line waited up to a panel period for the tick.
TICK_DATED_OVERHEAD_S = PANEL_PERIOD_S / 2
TICK_DATED_VAR_S2 = PANEL_PERIOD_S**2 / 12
#: Candidate servo speeds (× nominal) and dead bands (µs) of the grid, and latencies (s).
SPEED_GRID = tuple(float(v) for v in np.round(np.geomspace(0.25, 3.0, 19), 4))
DEADBAND_GRID = tuple(float(v) for v in np.arange(0.0, 30.1, 2.0))
LATENCY_GRID = tuple(float(v) for v in np.arange(0.0, 0.2005, 0.001))
#: With a camera, the plate poses also choose among speeds this many times finer than the grid's, from the grid
#: point below the ball's best to the one above (the trims move by several µs when the replay's speed is 5 % off).
FINE_SPEED_STEPS = 4
#: A window: this much burn-in of the servos, then the ball's path compared over FIT_S (readings from
#: LATENCY_GRID's largest value on, so that every candidate latency sees the same readings).
BURN_IN_S = 1.0
FIT_S = 1.0
#: Held-out windows: the ball's start fitted over the first PAST_S, then predicted over the horizons.
PAST_S = 0.6
HORIZONS_S = (0.5, 1.0)
#: A parameter whose bootstrap spread (one sigma) exceeds this fraction of its grid's span is undetermined.
UNDETERMINED_FRACTION = 0.2
BOOTSTRAP = 200
#: m: the thickest markers ``sysid --marker-height-mm`` takes (tiles cut from a thick sheet).
MAX_MARKER_HEIGHT = 0.02


@dataclass(frozen=True)
class FlightLog:
    """The parts of a deploy log a fit reads.

    Attributes:
        path: the file.
        t: (K,) s, each tick's time on the loop's clock.
        pulses: (K, 6) µs sent at each tick.
        usable: (K,) whether the tick ran normally (not stale, invalid, missed, held or homing).
        reading_t: (M,) s, each distinct reading's time on the loop's clock: when it arrived (or the tick that
            read it).
        reading_xy: (M, 2) m, the readings (plate frame).
        rate_hz: the loop's rate.
        dated_at_ticks: whether the readings are dated at the tick that read them (most of them at a tick's
            time) rather than when they arrived between ticks.
        plate: with a camera (the log's plate columns), each distinct frame's time and plate pose
            (:class:`~stewart_gym.plate_trims.PlateLog`); None without.
        poses: (K, 6) the pose asked for at each tick (m, rad), where the log has the pose columns; else None.
        digest: the sha256 of the file's text: the same log under two names is told apart from two logs.
    """

    path: str
    t: np.ndarray
    pulses: np.ndarray
    usable: np.ndarray
    reading_t: np.ndarray
    reading_xy: np.ndarray
    rate_hz: float
    dated_at_ticks: bool = False
    plate: PlateLog | None = None
    poses: np.ndarray | None = None
    digest: str = ""

    @property
    def read_overhead_s(self) -> float:
        """s: how much older than the twin's latency a reading is at the time the log gives it, on average."""
        return READ_OVERHEAD_S + (TICK_DATED_OVERHEAD_S if self.dated_at_ticks else 0.0)

    @property
    def read_time_var_s2(self) -> float:
        """s²: the variance of that age."""
        return READ_TIME_VAR_S2 + (TICK_DATED_VAR_S2 if self.dated_at_ticks else 0.0)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0


#: The fewest windows a fit takes.
MIN_FIT_WINDOWS = 5
#: A deploy log's columns of the pose asked for at each tick.
POSE_COLUMNS = ("x_m", "y_m", "z_m", "roll", "pitch", "yaw")
#: The share of a log's ticks away from home whose pulses must be the geometry's and calibration's for the pose
#: asked for, to the log's rounding: below it, the log is another build's (or another calibration's).
MIN_POSE_AGREEMENT = 0.25


def pose_agreement(log: FlightLog, geometry: Any, calibration: ServoCalibration) -> float | None:
    """The share of ``log``'s ticks away from home (a pulse over 20 µs from neutral) whose pulses are the ones
    ``geometry`` and ``calibration`` give for the pose asked for, to within what the log's rounding (poses to 1e-6,
    pulses to 0.01 µs) allows; None where the log has no poses or fewer than 20 such ticks. A tick the safety layer
    held back disagrees, so a log of the right build agrees on most ticks and one of another build on next to
    none."""
    from stewart_gym.kinematics import inverse_kinematics

    if log.poses is None:
        return None
    away = np.abs(log.pulses - calibration.neutral_us).max(axis=1) > 20.0
    if away.sum() < 20:
        return None
    poses = log.poses[away]

    def pulses(p: np.ndarray) -> np.ndarray:
        return calibration.pulse_widths(inverse_kinematics(geometry, p).actuators)

    expected = pulses(poses)
    step = 1e-6  # each coordinate's slope, for the tolerance its rounding to 1e-6 brings
    slack = sum(np.abs(pulses(poses + step * np.eye(6)[k]) - expected) for k in range(6)) * 0.5
    gap = np.nan_to_num(np.abs(expected - log.pulses[away]), nan=np.inf)
    return float(np.mean(np.all(gap <= 0.02 + slack, axis=1)))


def unfit_reason(path: str | Path, plate_half: Sequence[float] = (0.15, 0.15), holdout: float = 0.3) -> str | None:
    """Why :func:`fit_twin` could not fit a twin from the log at ``path`` alone (not a log it reads, too short, too
    few windows with the ball on the plate), in words; None where it can."""
    try:
        _fit_windows([read_log(path, plate_half)], holdout)
    except ConfigError as exc:
        return str(exc)
    return None


def _fit_windows(logs: Sequence[FlightLog], holdout: float) -> tuple[list[_Window], list[_Window]]:
    """The logs' windows to fit and held out; :class:`ConfigError` where there are too few to fit."""
    windows = _windows(list(logs), holdout)
    fit_w = [w for w in windows if not w.heldout]
    if len(fit_w) < MIN_FIT_WINDOWS:
        raise ConfigError(f"the logs give {len(fit_w)} usable windows to fit ({MIN_FIT_WINDOWS} or more needed): log "
                          "longer runs with the ball on the plate (identify --duration 60)")  # fmt: skip
    return fit_w, [w for w in windows if w.heldout]


def read_log(path: str | Path, plate_half: Sequence[float] = (0.15, 0.15)) -> FlightLog:
    """A deploy log (``identify``'s or ``deploy``'s), checked: its columns, finite pulses, at least 5 s of ticks
    and readings. Readings off the plate (``plate_half`` m, with a 10 mm margin) or not finite are dropped, and a
    reading read at two ticks is kept once. Raises :class:`ConfigError` naming the file."""
    from stewart_gym.inputs import read_text

    text = read_text(path, "deploy log", error=ConfigError)
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise ConfigError(f"{path}: empty; give a log that identify or deploy wrote")
    header = rows[0]
    twice = sorted({c for c in header if header.count(c) > 1})
    known = set(log_columns(0, 0, plate=True))
    unknown = [c for c in header if c not in known and not re.fullmatch(r"(obs|action)\d+", c)]
    if twice or unknown:
        raise ConfigError(f"{path}: " + (f"column(s) {twice} given more than once" if twice else
                                         f"unknown column(s) {unknown[:5]}") + "; a deploy log has the columns deploy "
                          "and identify write (docs: Configuration files, deploy log)")  # fmt: skip
    need = ["t_s", *(f"pulse{i}_us" for i in range(6)), *LOG_READING_COLUMNS]
    missing = [c for c in need if c not in header]
    if missing:
        raise ConfigError(f"{path}: not a deploy log with readings (no column {missing[0]!r}); write one with "
                          "stewart-gym identify, or deploy with this version")  # fmt: skip
    col = {name: header.index(name) for name in header}
    flags = [c for c in ("stale", "invalid", "missed_deadline", "held", "homing") if c in col]
    lines = [k + 2 for k, r in enumerate(rows[1:]) if r]  # each row's line in the file
    body = [r for r in rows[1:] if r]
    if body and not text.endswith("\n") and len(body[-1]) != len(header):  # a last line cut as it was written
        body, lines = body[:-1], lines[:-1]  # (a crash or a full disk): the rows before it stand

    def parsed(r: list[str]) -> tuple[float, list[float], list[float], list[int]]:
        if len(r) != len(header):
            raise ValueError(f"{len(r)} fields, the header has {len(header)}")
        return (float(r[col["t_s"]]), [float(r[col[f"pulse{i}_us"]]) for i in range(6)],
                [float(r[col[c]]) if r[col[c]] != "" else math.nan for c in LOG_READING_COLUMNS],
                [int(r[col[c]]) for c in flags])  # fmt: skip

    values = []
    for line, r in zip(lines, body):
        try:
            values.append(parsed(r))
        except ValueError as exc:
            raise ConfigError(f"{path}: line {line} is not a deploy log's row ({exc}); the file may be cut or "
                              "edited") from None  # fmt: skip
    t = np.array([v[0] for v in values])
    pulses = np.array([v[1] for v in values]).reshape(len(values), 6)
    raw = np.array([v[2] for v in values]).reshape(len(values), len(LOG_READING_COLUMNS))
    bad = np.array([v[3] for v in values], dtype=np.int64).reshape(len(values), len(flags))
    if len(t) < 2:
        raise ConfigError(f"{path}: {len(t)} tick(s); a fit needs a log of 5 s or more (identify runs 60 s)")
    wrong = np.flatnonzero(~np.isfinite(t) | np.r_[False, ~(np.diff(t) > 0)])
    if wrong.size:
        raise ConfigError(f"{path}: line {lines[wrong[0]]}: t_s {t[wrong[0]]:g} is not finite, or not after the "
                          "tick before it; the tick times must be finite and increasing")  # fmt: skip
    nonfinite = np.argwhere(~np.isfinite(pulses))
    if nonfinite.size:
        k, channel = (int(v) for v in nonfinite[0])
        raise ConfigError(f"{path}: line {lines[k]}: pulse{channel}_us is {pulses[k, channel]:g}, not a finite pulse "
                          "width")  # fmt: skip
    rate = 1.0 / float(np.median(np.diff(t)))
    half = np.asarray(plate_half, dtype=float) + 0.010
    ok = np.all(np.isfinite(raw), axis=1)
    ok[ok] &= np.all(np.abs(raw[ok, :2]) <= half, axis=1)
    readings = raw[ok]
    _, first = np.unique(readings[:, 2], return_index=True)
    readings = readings[np.sort(first)]
    readings = readings[np.argsort(readings[:, 2], kind="stable")]
    if t[-1] - t[0] < 5.0 or len(readings) < 5 * rate / 2:
        span = math.floor((t[-1] - t[0]) * 100) / 100  # (4.996 s is not "5.0 s")
        raise ConfigError(f"{path}: {span:.2f} s of ticks, with {len(readings)} readings of the ball on the "
                          f"plate; a fit needs at least 5 s of ticks and {math.ceil(5 * rate / 2)} readings "
                          "(identify runs 60 s)")  # fmt: skip
    at_tick = np.abs(readings[:, 2] - t[np.clip(np.searchsorted(t, readings[:, 2]), 0, len(t) - 1)]) < 2e-4
    plate = None
    if all(c in col for c in LOG_PLATE_COLUMNS):
        try:
            seen = np.array([[float(r[col[c]]) if r[col[c]] != "" else math.nan for c in LOG_PLATE_COLUMNS]
                             for r in body])  # fmt: skip
        except (ValueError, IndexError) as exc:
            raise ConfigError(f"{path}: a plate pose is not a number ({exc}); the file may be cut or edited") from None
        seen = seen[np.all(np.isfinite(seen), axis=1)]
        _, first = np.unique(seen[:, :6], axis=0, return_index=True)  # a frame read at several ticks: once
        seen = seen[np.sort(first)]
        plate = PlateLog(t, pulses, seen[:, 6], seen[:, :6])
    poses = None
    if all(c in col for c in POSE_COLUMNS):
        try:
            poses = np.array([[float(r[col[c]]) for c in POSE_COLUMNS] for r in body]).reshape(len(body), 6)
        except ValueError as exc:
            raise ConfigError(f"{path}: a pose asked for is not a number ({exc}); the file may be cut or "
                              "edited") from None  # fmt: skip
    return FlightLog(str(path), t, pulses, ~np.any(bad.astype(bool), axis=1), readings[:, 2], readings[:, :2], rate,
                     dated_at_ticks=bool(np.mean(at_tick) > 0.5), plate=plate, poses=poses,
                     digest=hashlib.sha256(text.encode()).hexdigest())  # fmt: skip


@dataclass
class FitResult:
    """What :func:`fit_twin` found.

    Attributes:
        twin: the fitted twin (with its ``[fit]`` table).
        total_latency_ms: the fitted sensor + servo latency, as the twin counts it.
        tilt_accel: (2,) m/s², the ball's constant acceleration from the plate's tilt offset.
        noise_mm: the readings' spread around the fit.
        prediction: horizon (s) → {"nominal": RMS mm, "fitted": RMS mm, "windows": n} on held-out windows.
        fit_windows, heldout_windows: how many windows each part had.
        notes: ``"table.key"`` → why it is undetermined (or what bounds it).
        examples: a few held-out windows' paths for the report's figure: (t, logged, nominal, fitted).
        trim_fit: each servo's trim from the camera's plate poses (:mod:`stewart_gym.plate_trims`); None where the
            logs hold no plate poses (the trims are then the smallest that make the tilt offset).
    """

    twin: Twin
    total_latency_ms: float
    tilt_accel: np.ndarray
    noise_mm: float
    prediction: dict[float, dict[str, float]]
    fit_windows: int
    heldout_windows: int
    notes: dict[str, str] = field(default_factory=dict)
    examples: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    trim_fit: TrimFit | None = None
    #: what read the ball in the logs: "panel", "camera", or "panel and camera"
    sensor: str = "panel"

    def lines(self) -> list[str]:
        """The fit as text: each value with its uncertainty, then what could not be determined."""
        tw = self.twin
        s = tw.sigma
        noise = {"panel": "panel noise", "camera": "camera noise"}.get(self.sensor, "reading noise")
        ball = twin_ball(tw)
        out = [f"fitted on {self.fit_windows} windows; predictions on {self.heldout_windows} held-out windows, "
               f"rolling a {2e3 * ball.radius:.1f} mm {'hollow' if ball.hollow else 'solid'} ball of "
               f"{1e3 * ball.mass:.1f} g (--start's [ball], else the nominal one)",
               f"  total latency  {self.total_latency_ms:6.1f} ms ± {s.get('servos.latency_ms', 0):.1f} "
               f"(sensor {tw['sensor.latency_ms']:.0f} + servos {tw['servos.latency_ms']:.1f})",
               f"  servo speed    {tw['servos.speed_scale']:6.2f} × ± {s.get('servos.speed_scale', 0):.2f}",
               f"  dead band      {tw['servos.deadband_us']:6.1f} µs ± {s.get('servos.deadband_us', 0):.1f}",
               f"  {noise:<15}{tw['sensor.noise_mm']:6.2f} mm ± {s.get('sensor.noise_mm', 0):.2f}"
               + ("" if self.sensor == "panel" else " (a twin's [sensor] table is the touch panel's: a simulated "
                  "camera keeps its own model's noise)"),
               f"  tilt offset    ball acceleration ({self.tilt_accel[0] * 1e3:+.0f}, {self.tilt_accel[1] * 1e3:+.0f}) "
               f"mm/s²" + ("" if self.trim_fit else f": trims {', '.join(f'{v:+.0f}' for v in tw['servos.trim_us'])} µs")]
        if self.trim_fit is not None:
            f = self.trim_fit
            out.append(f"  servo trims    {', '.join(f'{v:+.1f}' for v in f.trims_us)} µs ± "
                       f"{', '.join(f'{v:.1f}' for v in f.sigma_us)} (from {f.frames} camera frames of the plate; "
                       f"residual {f.rms_m * 1e3:.2f} mm RMS; servos replayed at "
                       f"{f.servo.max_speed / ServoSpec().max_speed:.2f}× speed, {f.servo.deadband_us:g} µs dead "
                       "band)")  # fmt: skip
        for h, row in self.prediction.items():
            ratio = row["nominal"] / max(row["fitted"], 1e-9)
            verdict = (f"{ratio:.1f}× better" if ratio >= 1.0 else
                       f"{1.0 / ratio:.1f}× worse: the log may be too short or too quiet for the fit (run identify "
                       "longer), or the ball is not the one the replays rolled (give your ball's twin with --start)")
            out.append(f"  held-out {h:g} s prediction RMS: nominal twin {row['nominal']:.2f} mm, fitted "
                       f"{row['fitted']:.2f} mm ({verdict})")
        if tw.undetermined:
            out.append("undetermined (and what the twin holds for each):")
            out.extend(f"  {name}: {self.notes.get(name, '')}" for name in tw.undetermined)
        return out


# ------------------------------------------------------------------ windows
@dataclass(frozen=True)
class _Window:
    log: int
    start: int  # the first tick (burn-in starts here)
    ticks: int  # how many ticks the window simulates
    heldout: bool


def _windows(logs: list[FlightLog], holdout: float) -> list[_Window]:
    """Windows of burn-in + latency margin + FIT_S (held out: + PAST_S + the longest horizon), one after another,
    in stretches of usable ticks with readings throughout (no gap over 0.1 s)."""
    out = []
    margin = max(LATENCY_GRID)
    for li, log in enumerate(logs):
        dt = 1.0 / log.rate_hz
        split = log.t[0] + (1.0 - holdout) * (log.t[-1] - log.t[0])
        k = int(round(1.0 / dt))  # the first second: the controller takes the ball
        while True:
            heldout = log.t[min(k, len(log.t) - 1)] >= split
            span = BURN_IN_S + margin + (PAST_S + max(HORIZONS_S) if heldout else FIT_S)
            n = int(round(span / dt))
            if k + n >= len(log.t):
                break
            t0, t1 = log.t[k], log.t[k + n]
            inside = log.reading_t[(log.reading_t >= t0) & (log.reading_t <= t1)]
            gaps = np.diff(np.concatenate([[t0], inside, [t1]]))
            fits = log.t[k + n - 1] < split or heldout
            if fits and log.usable[k:k + n].all() and len(inside) and gaps.max() <= 0.1:
                out.append(_Window(li, k, n, heldout))
                k += n
            else:
                k += max(1, n // 4)
    return out


def twin_ball(twin: Twin) -> BallSpec:
    """The ball ``twin`` sets (its radius, mass, rolling friction and shell), which the replays roll."""
    return EpisodeParams.from_twin(twin, BallSpec(), ServoSpec(), TouchPanelSpec()).ball


def _simulate(geometry: Any, calibration: ServoCalibration, logs: list[FlightLog], windows: list[_Window],
              servos: list[ServoSpec], start: tuple[np.ndarray, np.ndarray] | None = None, *,
              ball: BallSpec) -> np.ndarray:  # fmt: skip
    """Every window under every candidate servo, with ``ball``: the ball's path (W, C, steps + 1, 2) m from the end
    of the burn-in, the ball placed there with ``start`` (positions and velocities, (W, 2) each), else at rest at
    the window's first reading."""
    rate = logs[0].rate_hz
    W, C = len(windows), len(servos)
    sim = BatchedSim(geometry, n=W * C, calibration=calibration, physics_hz=int(round(rate)) * 4,
                     control_hz=int(round(rate)), ball_spec=ball)  # fmt: skip
    sim.reset(servo_specs=[s for _ in windows for s in servos])
    burn = int(round(BURN_IN_S * rate))
    steps = max(w.ticks for w in windows) - burn
    pulses = np.empty((W, burn + steps, 6))
    start_xy = np.zeros((W, 2))
    for i, w in enumerate(windows):
        log = logs[w.log]
        p = log.pulses[w.start:w.start + w.ticks]
        pulses[i, :len(p)] = p
        pulses[i, len(p):] = p[-1]
        after = np.searchsorted(log.reading_t, log.t[w.start + burn])
        start_xy[i] = log.reading_xy[min(after, len(log.reading_t) - 1)]
    start_v = np.zeros((W, 2))
    if start is not None:
        start_xy, start_v = start
    path = np.empty((W, C, steps + 1, 2))
    for j in range(burn + steps):
        if j == burn:
            sim.place_ball(np.repeat(start_xy, C, axis=0), np.repeat(start_v, C, axis=0))
            path[:, :, 0] = sim.ball_xy.reshape(W, C, 2)
        sim.command(np.repeat(pulses[:, j], C, axis=0))
        sim.step()
        if j >= burn:
            path[:, :, j - burn + 1] = sim.ball_xy.reshape(W, C, 2)
    return path


def _readings(logs: list[FlightLog], windows: list[_Window], lo: float, hi: float) -> tuple[np.ndarray, ...]:
    """Each window's readings between ``lo`` and ``hi`` s after its burn-in (padded): u (W, R) s from the burn-in's
    end, xy (W, R, 2), mask (W, R)."""
    rate = logs[0].rate_hz
    burn = int(round(BURN_IN_S * rate))
    picked = []
    for w in windows:
        log = logs[w.log]
        t0 = log.t[w.start + burn]
        sel = (log.reading_t >= t0 + lo) & (log.reading_t <= t0 + hi)
        picked.append((log.reading_t[sel] - t0, log.reading_xy[sel]))
    R = max(1, max(len(p[0]) for p in picked))
    u, xy, mask = np.zeros((len(windows), R)), np.zeros((len(windows), R, 2)), np.zeros((len(windows), R))
    for i, (ui, xyi) in enumerate(picked):
        u[i, :len(ui)], xy[i, :len(ui)], mask[i, :len(ui)] = ui, xyi, 1.0
    return u, xy, mask


def _at(path: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
    """``path`` (W, C, S, 2) sampled every ``dt`` from 0, at times ``tau`` (W, R) (linear; clamped to the path)."""
    S = path.shape[2]
    x = np.clip(tau / dt, 0.0, S - 1.000001)
    i = np.floor(x).astype(int)
    w = (x - i)[:, None, :, None]
    shape = (*path.shape[:2], tau.shape[1], 2)

    def gather(k: np.ndarray) -> np.ndarray:
        return np.take_along_axis(path, np.broadcast_to(k[:, None, :, None], shape), axis=2)

    return gather(i) * (1 - w) + gather(i + 1) * w


# ---------------------------------------------------------------------- fit
def _statistics(path: np.ndarray, u: np.ndarray, xy: np.ndarray, mask: np.ndarray,
                dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Per window, candidate, latency and axis: the sufficient statistics of the least squares with each window's
    start and one shared tilt acceleration eliminated: c = |P r|², b = <P q, P r>, and per window A = |P q|²;
    also n, the readings per window."""
    X = np.stack([np.ones_like(u), u], axis=2) * mask[:, :, None]  # (W, R, 2): each window's start, eliminated
    Ginv = np.linalg.inv(np.einsum("wri,wrj->wij", X, X) + 1e-12 * np.eye(2))
    q = 0.5 * u**2 * mask
    Pq = q - np.einsum("wri,wij,wj->wr", X, Ginv, np.einsum("wrj,wr->wj", X, q))  # q off span{1, u}: I − X G⁻¹ Xᵀ
    A = np.einsum("wr,wr->w", Pq, Pq)
    W, C = path.shape[:2]
    c = np.empty((W, C, len(LATENCY_GRID), 2))
    b = np.empty_like(c)
    for li, lat in enumerate(LATENCY_GRID):
        r = (xy[:, None] - _at(path, u - lat, dt)) * mask[:, None, :, None]  # (W, C, R, 2)
        Xr = np.einsum("wrk,wcra->wcka", X, r)
        c[:, :, li] = np.einsum("wcra,wcra->wca", r, r) - np.einsum("wcka,wkj,wcja->wca", Xr, Ginv, Xr)
        b[:, :, li] = np.einsum("wr,wcra->wca", Pq, r)
    return c, b, A, mask.sum(axis=1)


def _start_states(path: np.ndarray, u: np.ndarray, xy: np.ndarray, mask: np.ndarray, dt: float, lat: float,
                  accel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each window's ball at the end of its burn-in (positions, velocities (W, 2)), from the readings: where
    ``path`` (W, S, 2; the ball placed at rest there) would have to start to fit them, with latency ``lat`` and
    the shared acceleration ``accel``."""
    X = np.stack([np.ones_like(u), u], axis=2) * mask[:, :, None]
    Ginv = np.linalg.inv(np.einsum("wri,wrj->wij", X, X) + 1e-12 * np.eye(2))
    r = (xy - _at(path[:, None], u - lat, dt)[:, 0] - 0.5 * accel * (u**2)[:, :, None]) * mask[:, :, None]
    beta = np.einsum("wij,wrj,wra->wia", Ginv, X, r)  # (W, 2 coefficients, 2 axes): y ≈ path + β0 + β1 u
    # in the path's own time τ = u − lat: the offset β0 + β1 (τ + lat) + ½ a (τ + lat)², at τ = 0
    return path[:, 0] + beta[:, 0] + beta[:, 1] * lat + 0.5 * accel * lat**2, beta[:, 1] + accel * lat


def _cost(c: np.ndarray, b: np.ndarray, A: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total cost (C, L) over windows weighted by ``weights`` (W,), with the shared acceleration (C, L, 2)."""
    cw = np.einsum("w,wcla->cla", weights, c)
    bw = np.einsum("w,wcla->cla", weights, b)
    aw = float(weights @ A) + 1e-18
    return (cw - bw**2 / aw).sum(axis=2), bw / aw


def _refine(values: Sequence[float], costs: np.ndarray, i: int) -> float:
    """The minimum of a parabola through ``costs`` at i − 1, i, i + 1 (``values`` there), kept between them."""
    if i <= 0 or i >= len(values) - 1:
        return float(values[i])
    x0, x1, x2 = values[i - 1], values[i], values[i + 1]
    y0, y1, y2 = costs[i - 1], costs[i], costs[i + 1]
    den = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
    bb = (x2**2 * (y0 - y1) + x1**2 * (y2 - y0) + x0**2 * (y1 - y2)) / den
    if a <= 0:
        return float(x1)
    return float(np.clip(-bb / (2 * a), x0, x2))


def _best(total: np.ndarray) -> tuple[float, float, float, tuple[int, int, int]]:
    """(speed, dead band, latency s) at the cost's minimum over the grid (C = speeds × dead bands, L), refined."""
    S, D = len(SPEED_GRID), len(DEADBAND_GRID)
    grid = total.reshape(S, D, len(LATENCY_GRID))
    si, di, li = np.unravel_index(int(np.argmin(grid)), grid.shape)
    return (_refine(SPEED_GRID, grid[:, di, li], si), _refine(DEADBAND_GRID, grid[si, :, li], di),
            _refine(LATENCY_GRID, grid[si, di, :], li), (int(si), int(di), int(li)))  # fmt: skip


def _trims_for(geometry: Any, calibration: ServoCalibration, accel: np.ndarray) -> np.ndarray:
    """The smallest six trims (µs) that tilt the plate so that a resting ball accelerates by ``accel`` (m/s²,
    plate frame): the pulses of a small roll and of a small pitch, the ball's acceleration under each measured in
    the batched simulator, and the combination that gives ``accel``."""
    from stewart_gym.kinematics import inverse_kinematics

    angle = 0.01
    home = calibration.pulse_widths(inverse_kinematics(geometry, np.zeros(6)).servo_angles)
    shapes = []
    for axis in (3, 4):  # roll, pitch
        pose = np.zeros(6)
        pose[axis] = angle
        shapes.append(calibration.pulse_widths(inverse_kinematics(geometry, pose).servo_angles) - home)
    sim = BatchedSim(geometry, n=2, calibration=calibration)
    sim.reset(servo_specs=[replace(ServoSpec(), trim_error_us=tuple(-d)) for d in shapes])  # held at home, tilted
    for _ in range(25):  # the servos settle on the tilt
        sim.command(np.repeat(home[None], 2, axis=0))
        sim.step()
    sim.place_ball(np.zeros((2, 2)), np.zeros((2, 2)))
    steps = 10
    for _ in range(steps):
        sim.command(np.repeat(home[None], 2, axis=0))
        sim.step()
    response = (2.0 * sim.ball_xy / (steps * sim.dt) ** 2).T  # (2 axes, 2 shapes): acceleration per shape
    mix = np.linalg.solve(response, np.asarray(accel, dtype=float))
    return -(mix[0] * shapes[0] + mix[1] * shapes[1])


@one_blas_thread  # its solves and replays are hot loops of matrix products (stewart_gym.blas)
def fit_twin(logs: Sequence[FlightLog], geometry: Any = "servo-hexapod", calibration: ServoCalibration | None = None,
             start: Twin | None = None, holdout: float = 0.3, seed: int = 0,
             on_progress: Any = None, marker_height: float = 0.0) -> FitResult:  # fmt: skip
    """Fit a twin to ``logs`` (see the module's description). ``start`` is the twin the fit changes (its ball,
    plate and sensor split kept; default nominal); ``holdout`` the fraction of each log kept out of the fit;
    ``marker_height`` (m) how far above the plate's top a camera's markers lie (their thickness)."""
    from stewart_gym.presets import load_geometry

    if not (math.isfinite(marker_height) and 0.0 <= marker_height <= MAX_MARKER_HEIGHT):
        raise ConfigError(f"the markers' height above the plate must be 0 to {MAX_MARKER_HEIGHT * 1e3:g} mm, got "
                          f"{marker_height * 1e3:g} mm")  # fmt: skip
    if not logs:
        raise ConfigError("sysid needs at least one log")
    rates = {round(log.rate_hz) for log in logs}
    if len(rates) != 1:
        raise ConfigError(f"the logs ran at different rates ({sorted(rates)} Hz): fit logs of one rate together")
    if not 0.0 <= holdout <= 0.8:
        raise ConfigError(f"holdout must be a fraction in [0, 0.8], got {holdout!r}")
    geo = load_geometry(geometry)
    cal = calibration or ServoCalibration.default(geo)
    for log in logs:  # pulses the calibration could not have sent: another calibration's log, or an edited one
        outside = ~cal.in_range(log.pulses)
        if outside.any():
            tick, channel = (int(v) for v in np.argwhere(outside)[0])
            raise ConfigError(f"{log.path}: pulse{channel}_us {log.pulses[tick, channel]:g} µs (tick {tick + 1}, t_s "
                              f"{log.t[tick]:g}) is outside the calibration's [{cal.min_us[channel]:g}, "
                              f"{cal.max_us[channel]:g}] µs ({int(outside.sum())} pulse(s) in all): give the "
                              "--calibration the log was run with")  # fmt: skip
    seen: dict[str, str] = {}
    for log in logs:  # a log under two names would count its windows twice (and narrow the uncertainties)
        if log.digest and log.digest in seen:
            raise ConfigError(f"{seen[log.digest]} and {log.path} hold the same log: it would count its windows "
                              "twice (and narrow the uncertainties); give it once")  # fmt: skip
        seen[log.digest] = log.path
    for log in logs:  # another build's log (or another calibration's) would fit a twin to the wrong plant
        agreement = pose_agreement(log, geo, cal)
        if agreement is not None and agreement < MIN_POSE_AGREEMENT:
            raise ConfigError(f"{log.path}: its pulses are not what geometry {geo.name!r} and this calibration give "
                              f"for the poses it asked for ({100 * agreement:.0f} % of its ticks away from home "
                              "agree): give the --geometry and --calibration it was run with")  # fmt: skip
    given = start is not None  # a --start twin: its values stand where the logs cannot determine them
    start = start or Twin()
    ball = twin_ball(start)  # the replays' ball: --start's (a ping-pong ball rolls at 3/5 g sin θ, a steel one 5/7)
    fit_w, held_w = _fit_windows(logs, holdout)
    servos = [_servo(s, d) for s in SPEED_GRID for d in DEADBAND_GRID]
    rate = logs[0].rate_hz
    dt = 1.0 / rate
    overhead = float(np.mean([log.read_overhead_s for log in logs]))
    read_var = float(np.mean([log.read_time_var_s2 for log in logs]))
    margin = max(LATENCY_GRID)
    u, xy, mask = _readings(list(logs), fit_w, margin, margin + FIT_S)
    ones = np.ones(len(fit_w))
    start_state = None
    for done in (0.35, 0.7):  # twice: the second time each window's ball starts where the first fit put it
        path = _simulate(geo, cal, list(logs), fit_w, servos, start_state, ball=ball)
        c, b, A, n = _statistics(path, u, xy, mask, dt)
        total, accel = _cost(c, b, A, ones)
        speed, band, lat, (si, di, li) = _best(total)
        best = accel.reshape(len(SPEED_GRID), len(DEADBAND_GRID), -1, 2)[si, di, li]
        start_state = _start_states(path[:, si * len(DEADBAND_GRID) + di], u, xy, mask, dt, LATENCY_GRID[li], best)
        if on_progress:
            on_progress(done)
    camera = [log.plate for log in logs if log.plate is not None]
    trim_fit = None
    plate_chose = bool(camera) and usable_frames(camera) >= MIN_FRAMES
    if plate_chose:  # the plate poses choose the servos among all the grid, the ball's best first
        from stewart_gym.sim.urdf import MechanismSpec

        ball_best = si * len(DEADBAND_GRID) + di
        candidates = [servos[ball_best], *servos[:ball_best], *servos[ball_best + 1:], *_finer_servos(si, di)]
        trim_fit = fit_trims(geo, cal, camera, candidates, lat, MechanismSpec().plate_top + marker_height)
        speed, band = trim_fit.servo.max_speed / ServoSpec().max_speed, trim_fit.servo.deadband_us
        si = int(np.argmin(np.abs(np.log(np.array(SPEED_GRID) / speed))))  # the grid's nearest, for the latency
        di = DEADBAND_GRID.index(band)
        grid = total.reshape(len(SPEED_GRID), len(DEADBAND_GRID), len(LATENCY_GRID))
        li = int(np.argmin(grid[si, di]))  # the latency for those servos
        lat = _refine(LATENCY_GRID, grid[si, di], li)
    best_accel = accel.reshape(len(SPEED_GRID), len(DEADBAND_GRID), -1, 2)[si, di, li]
    ci = si * len(DEADBAND_GRID) + di
    best_path = path[:, ci]  # (W, S, 2)
    speed_sq = np.mean(np.diff(best_path, axis=1) ** 2, axis=(1, 2)) / dt**2  # (W,) per axis, m²/s²
    # each window's squared residual at the best fit, the shared acceleration taken out
    sse = (c[:, ci, li] - 2 * best_accel * b[:, ci, li] + best_accel**2 * A[:, None]).sum(axis=1)

    def noise_of(weights: np.ndarray) -> float:
        """The reading noise, mm, from the windows so weighted: the residual's variance less the timing scatter."""
        dof = max(float(weights @ (2 * n - 4)) - 2, 1.0)
        var = float(weights @ sse) / dof - read_var * float(weights @ speed_sq) / float(weights.sum())
        return math.sqrt(max(var, 0.0)) * 1e3

    noise_mm = noise_of(ones)
    # the bootstrap: the same fit on windows drawn with replacement
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(BOOTSTRAP):
        weights = np.bincount(rng.integers(len(fit_w), size=len(fit_w)), minlength=len(fit_w)).astype(float)
        tb, _ = _cost(c, b, A, weights)
        if plate_chose:  # the servos stay the plate's: the latency for them
            along = tb.reshape(len(SPEED_GRID), len(DEADBAND_GRID), len(LATENCY_GRID))[si, di]
            sb, db, lb = speed, band, _refine(LATENCY_GRID, along, int(np.argmin(along)))
        else:
            sb, db, lb, _ = _best(tb)
        draws.append((sb, db, lb, noise_of(weights)))
    spread = np.std(np.array(draws), axis=0)
    if plate_chose:  # the plate poses pick the servos: half the grid's spacing around them
        spread[0] = 0.25 * (SPEED_GRID[min(si + 1, len(SPEED_GRID) - 1)] - SPEED_GRID[max(si - 1, 0)])
        spread[1] = 0.5 * (DEADBAND_GRID[1] - DEADBAND_GRID[0])
    if on_progress:
        on_progress(0.85)
    total_ms = (lat - overhead) * 1e3
    sensor_ms = min(float(start["sensor.latency_ms"]), max(total_ms, 0.0))
    sigma = {"servos.speed_scale": float(max(spread[0], 0.01)), "servos.deadband_us": float(max(spread[1], 0.5)),
             "servos.latency_ms": float(max(spread[2] * 1e3, 0.5)), "sensor.noise_mm": float(max(spread[3], 0.01))}
    notes = {"sensor.latency_ms": "the ball shows the total latency only: the sensor keeps its value and the servos "
                                  "take the rest",
             "servos.trim_us": "the panel sees only the tilt the trims make together: these are the smallest trims "
                               "that make it (identify --sensor camera logs the plate's pose, which shows "
                               "each)"}  # fmt: skip
    undetermined = ["sensor.latency_ms", "servos.trim_us"]
    kept: dict[tuple[str, str], Any] = {}  # the --start twin's values that stand for undetermined ones
    for name, grid, value, sd in (("servos.speed_scale", SPEED_GRID, speed, spread[0]),
                                  ("servos.deadband_us", DEADBAND_GRID, band, spread[1])):  # fmt: skip
        span = grid[-1] - grid[0]
        if sd > UNDETERMINED_FRACTION * span:
            notes[name] = f"the bootstrap spread ({sd:.2g}) covers much of the search range: the logs hardly show it"
        elif value >= grid[-1] or value <= grid[0]:
            notes[name] = f"at the edge of the search ({value:g}): the logs only bound it"
        else:
            continue
        undetermined.append(name)
        if given:  # the user's value stands, with its own uncertainty
            kept[tuple(name.split("."))] = start[name]
            notes[name] += f"; the twin keeps --start's {start[name]:g}"
            sigma.pop(name)
            if name in start.sigma:
                sigma[name] = start.sigma[name]
        else:  # the search's best, as uncertain as the search is wide
            sigma[name] = max(sigma[name], UNDETERMINED_FRACTION * span)
            notes[name] += f"; the twin holds the search's best, ± {sigma[name]:.2g}"
    latency_span = LATENCY_GRID[-1] - LATENCY_GRID[0]
    if spread[2] > UNDETERMINED_FRACTION * latency_span:
        undetermined.append("servos.latency_ms")
        notes["servos.latency_ms"] = (f"the bootstrap spread ({spread[2] * 1e3:.0f} ms) covers much of the search "
                                      "range: the logs hardly show it; the twin holds the search's best")  # fmt: skip
    for key in ("ball.mass_scale", "ball.radius_scale", "ball.rolling_friction", "ball.hollow", "plate.friction",
                "plate.load_kg"):
        undetermined.append(key)
        notes[key] = "a ball rolling on the plate shows nothing of it; the twin keeps its value"
    notes["ball.hollow"] = ("not fitted (a shell's slower rolling would pass for slower servos): the replays rolled "
                            "the --start twin's ball, which the twin keeps")  # fmt: skip
    if camera and not plate_chose:
        notes["servos.trim_us"] = (f"the camera's logs hold {usable_frames(camera)} frames of the plate after their "
                                   f"first second, fewer than the {MIN_FRAMES} the trims need: these are the "
                                   "smallest trims that make the tilt offset")  # fmt: skip
    if trim_fit is not None:
        trims = trim_fit.trims_us
        undetermined.remove("servos.trim_us")
        sigma["servos.trim_us"] = float(max(np.max(trim_fit.sigma_us), 0.5))
    else:
        trims = _trims_for(geo, cal, best_accel)
        measured = given and "servos.trim_us" not in start.undetermined and any(start["servos.trim_us"])
        if measured:  # each servo's own, measured (not the nominal zeros of a --start that leaves them out): they stand
            kept[("servos", "trim_us")] = tuple(start["servos.trim_us"])
            notes["servos.trim_us"] = ("the panel sees only the tilt the trims make together: the twin keeps "
                                       "--start's, each servo's own")  # fmt: skip
            if "servos.trim_us" in start.sigma:
                sigma["servos.trim_us"] = start.sigma["servos.trim_us"]
    values = dict(start.values)
    values.update({("servos", "speed_scale"): float(np.clip(speed, 0.1, 5.0)),
                   ("servos", "deadband_us"): float(np.clip(band, 0.0, 50.0)),
                   ("servos", "latency_ms"): float(np.clip(total_ms - sensor_ms, 0.0, 200.0)),
                   ("servos", "trim_us"): tuple(float(np.clip(v, -200, 200)) for v in trims),
                   ("sensor", "latency_ms"): sensor_ms, ("sensor", "noise_mm"): float(np.clip(noise_mm, 0.0, 20.0))})
    values.update(kept)
    order = [f"{t}.{k}" for t, k in TWIN_FIELDS]
    twin = Twin(values, sigma, tuple(sorted(set(undetermined), key=order.index)), "sysid")
    sensor = "camera" if len(camera) == len(logs) else "panel and camera" if camera else "panel"
    result = FitResult(twin, total_ms, best_accel, noise_mm, {}, len(fit_w), len(held_w), notes, trim_fit=trim_fit,
                       sensor=sensor)  # fmt: skip
    if held_w:  # the fitted twin as it is written: --start's servos where they stand
        fitted = trim_fit.servo if plate_chose else servos[ci]
        if ("servos", "speed_scale") in kept or ("servos", "deadband_us") in kept:
            fitted = _servo(twin["servos.speed_scale"], twin["servos.deadband_us"])
        _predict(result, geo, cal, list(logs), held_w, start, lat, best_accel, fitted, overhead)
    if on_progress:
        on_progress(1.0)
    return result


def _servo(speed_scale: float, deadband_us: float) -> ServoSpec:
    """The nominal servo at ``speed_scale`` × its speed, with a dead band of ``deadband_us``."""
    nominal = ServoSpec()
    return replace(nominal, max_speed=nominal.max_speed * speed_scale, deadband_us=deadband_us)


def _finer_servos(si: int, di: int) -> list[ServoSpec]:
    """Servos at :data:`FINE_SPEED_STEPS` times the grid's speed resolution between the grid's speeds either side
    of ``SPEED_GRID[si]`` (the grid's own left out), each with the dead bands ``DEADBAND_GRID[di - 1 … di + 1]``."""
    low, high = max(si - 1, 0), min(si + 1, len(SPEED_GRID) - 1)
    speeds = np.geomspace(SPEED_GRID[low], SPEED_GRID[high], FINE_SPEED_STEPS * (high - low) + 1)
    speeds = [float(np.round(v, 4)) for v in speeds if not np.isclose(SPEED_GRID, v).any()]
    bands = DEADBAND_GRID[max(di - 1, 0):di + 2]
    return [_servo(s, d) for s in speeds for d in bands]


def _predict(result: FitResult, geo: Any, cal: ServoCalibration, logs: list[FlightLog], windows: list[_Window],
             start: Twin, lat: float, accel: np.ndarray, fitted: ServoSpec, overhead: float) -> None:  # fmt: skip
    """Held-out prediction errors of the nominal twin (``start``) and the fitted one (``lat``: its latency as the
    logs date the readings; ``overhead``: what the logs' dates add to a twin's latency).

    Each twin finds the ball's start from the past readings alone, in two passes as the fit does: first from rest
    at the first reading, then from the position and velocity that the past readings give. The second pass
    matters where the plate turns about its normal (identify's yaw moves with a camera): the ball's path then
    depends on its own velocity (the Coriolis term), which a correction added afterwards does not carry."""
    rate = logs[0].rate_hz
    dt = 1.0 / rate
    nominal_servo = _servo(start["servos.speed_scale"], start["servos.deadband_us"])
    ball = twin_ball(start)
    nominal_lat = start.total_latency_ms / 1e3 + overhead
    margin = max(LATENCY_GRID)
    u, xy, mask = _readings(logs, windows, margin, margin + PAST_S + max(HORIZONS_S))
    past = mask * (u <= margin + PAST_S)
    errors: dict[float, dict[str, list[float]]] = {h: {"nominal": [], "fitted": []} for h in HORIZONS_S}
    paths: dict[str, list[np.ndarray]] = {"nominal": [], "fitted": []}
    for name, servo, lt, acc in (("nominal", nominal_servo, nominal_lat, np.zeros(2)), ("fitted", fitted, lat, accel)):
        path = _simulate(geo, cal, logs, windows, [servo], ball=ball)
        path = _simulate(geo, cal, logs, windows, [servo], _start_states(path[:, 0], u, xy, past, dt, lt, acc),
                         ball=ball)  # fmt: skip
        pred = _at(path, u - lt, dt)[:, 0] + 0.5 * acc * (u**2)[:, :, None]
        r = xy - pred
        for w in range(len(windows)):  # the ball's start from the past readings only: position and velocity
            sel = past[w] > 0
            X = np.stack([np.ones(sel.sum()), u[w, sel]], axis=1)
            coef, *_ = np.linalg.lstsq(X, r[w, sel], rcond=None)
            predicted = pred[w] + coef[0] + np.outer(u[w], coef[1])
            err = np.linalg.norm(xy[w] - predicted, axis=1)
            for h in HORIZONS_S:
                ahead = (mask[w] > 0) & (u[w] > margin + PAST_S) & (u[w] <= margin + PAST_S + h)
                if ahead.any():
                    errors[h][name].append(float(np.mean(err[ahead] ** 2)))
            paths[name].append(predicted[mask[w] > 0])
    for w in range(min(3, len(windows))):
        keep = mask[w] > 0
        result.examples.append((u[w, keep] - margin, xy[w, keep], paths["nominal"][w], paths["fitted"][w]))
    for h in HORIZONS_S:
        result.prediction[h] = {k: math.sqrt(float(np.mean(v))) * 1e3 for k, v in errors[h].items()}
        result.prediction[h]["windows"] = len(errors[h]["fitted"])


#: The files :func:`write_report` writes into its folder.
REPORT_FILES = ("report.md", "paths.png")


def write_report(result: FitResult, folder: str | Path, logs: Sequence[str]) -> list[Path]:
    """``report.md`` (the fit, its uncertainties, the held-out predictions) and ``paths.png`` (logged and predicted
    ball paths of held-out windows) in ``folder``; the files written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    text = ["# sysid report", "", f"Logs: {', '.join(str(p) for p in logs)}", "", "```", *result.lines(), "```", ""]
    (folder / "report.md").write_text("\n".join(text), encoding="utf-8")
    written = [folder / "report.md"]
    if result.examples:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(len(result.examples), 2, figsize=(9, 2.6 * len(result.examples)), squeeze=False)
        for row, (t, logged, nominal, fitted) in zip(axes, result.examples):
            for a, ax in enumerate(row):
                ax.plot(t, logged[:, a] * 1e3, ".", ms=3, color="black", label="logged")
                ax.plot(t, nominal[:, a] * 1e3, "-", label="nominal twin")
                ax.plot(t, fitted[:, a] * 1e3, "-", label="fitted twin")
                ax.axvline(PAST_S, color="grey", lw=0.8)
                ax.set_ylabel(f"{'xy'[a]} (mm)")
        axes[-1][0].set_xlabel("s")
        axes[-1][1].set_xlabel("s")
        axes[0][0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(folder / "paths.png", dpi=90)
        plt.close(fig)
        written.append(folder / "paths.png")
    return written
