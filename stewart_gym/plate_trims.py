"""Each servo's trim from the plate poses a camera saw: the part of ``sysid`` that reads ``identify --sensor camera``.

A trim is a constant error in a servo's angle. The ball only feels the tilt the six make together; a camera on
the plate's markers sees the plate's whole pose, frame by frame, in its own frame (OpenCV's ``solvePnP``). The
camera's pose relative to the base is not known, so the fit finds it too:

- the logged pulses are replayed through the batched simulator with the servos ``sysid`` fitted (speed, dead
  band), without trims, which gives each servo's angle at every tick;
- a frame taken at time t shows the plate where the forward kinematics put it for those angles at ``t − τ``,
  each less its trim, as a camera at an unknown pose sees it;
- the trims (6, µs), the camera's rotation and position (6) and the delay τ are fitted together by nonlinear
  least squares (a soft-L1 loss, so that a bad frame counts little) on four points of the marker plane, 0.1 m
  from its centre, in every frame;
- a frame's time is known only to within part of a frame period, so a frame taken while the plate moves fast
  is further off: the fit measures that timing scatter from its residuals (against the plate's speed) and
  weighs each frame by it, then fits again;
- given several candidate servos (``sysid`` gives its whole grid of speeds and dead bands, the ball's best
  first), all are replayed in one batched run of their servos alone; the fit ranks them by how well their plate
  poses would fit the camera's after one Gauss–Newton step (first on every :data:`RANK_STRIDE`-th frame, then the
  :data:`SHORTLIST` best on all), solves again with the best, and ranks again from there, at most
  :data:`MAX_PICKS` times. A servo replayed with the wrong dead band stops elsewhere than the real one did, an
  error the trims would take up. The servo it settles on is also solved from the first guess, with the timing
  weights of its own residuals, and the solution whose frames fit better (unweighted) is kept: a solve that
  starts from another servo's solution can stay in that solution's minimum.

At any one pose, what a trim does to the plate a small shift of the camera would do too; what tells them apart
is how the kinematics change with the plate's tilt, height and yaw. That is why ``identify`` moves the plate in
height and yaw and in large tilt triplets when a camera watches it, and why the fit wants :data:`MIN_FRAMES`
frames or more. The trims' common part (every horn turned the same way: the plate's height) is the least
determined: the camera's depth is its least precise direction.

The uncertainties are the least-squares covariance with the residuals grouped by second (a frame's errors are
not independent of its neighbours'), so they grow where the log is short or the model misses.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from stewart_gym.blas import one_blas_thread
from stewart_gym.calibration import ServoCalibration
from stewart_gym.errors import ConfigError
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import forward_kinematics, rotation_matrix
from stewart_gym.sim import BatchedSim, ServoSpec

__all__ = ["MIN_FRAMES", "PlateLog", "TrimFit", "fit_trims", "rotation_from_vector", "usable_frames"]

#: The fewest distinct frames a fit uses (about 10 s of a 30 fps camera).
MIN_FRAMES = 200
#: The points of the marker plane compared in each frame, m (a square 0.2 m across, about the plate's size).
POINTS = np.array([[-0.1, 0.1, 0.0], [0.1, 0.1, 0.0], [0.1, -0.1, 0.0], [-0.1, -0.1, 0.0]])
#: The replay's physics steps per tick: the angles between ticks are interpolated from these.
SUBSTEPS = 4
#: Frames in the log's first second are left out: the controller takes the ball then.
SKIP_S = 1.0
#: The most times the fit moves to another candidate servo, each time solving again from the last solution and
#: ranking the :data:`SHORTLIST` anew from there.
MAX_PICKS = 3
#: How many of the candidates the first ranking puts first are ranked again after each move.
SHORTLIST = 8
#: With more candidates than :data:`SHORTLIST`, the first ranking looks at every this-th frame.
RANK_STRIDE = 4
#: m: the scale of the soft-L1 loss (a frame's point further off than this counts less than its square).
LOSS_SCALE_M = 0.001


@dataclass(frozen=True)
class PlateLog:
    """What a fit reads from one log: the ticks' times (K,) s and pulses (K, 6) µs, and each distinct frame's
    time (F,) s and plate pose (F, 6): rotation vector (rad) and position (m) in the camera's frame."""

    t: np.ndarray
    pulses: np.ndarray
    frame_t: np.ndarray
    frame_pose: np.ndarray


@dataclass(frozen=True)
class TrimFit:
    """The fitted trims (6,) µs with their one-sigma uncertainties, the delay τ (s) between a tick's angles and
    the frame that shows them, the RMS residual (m), the number of frames used, the servos the replay kept and
    the frames' timing scatter (s)."""

    trims_us: np.ndarray
    sigma_us: np.ndarray
    delay_s: float
    rms_m: float
    frames: int
    servo: ServoSpec
    timing_s: float


def rotation_from_vector(v: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from rotation vectors (..., 3) (Rodrigues' formula; OpenCV's convention)."""
    v = np.asarray(v, dtype=np.float64)
    angle = np.linalg.norm(v, axis=-1)[..., None, None]
    safe = np.where(angle > 1e-12, angle, 1.0)
    k = v / safe[..., 0]
    kx, ky, kz = k[..., 0], k[..., 1], k[..., 2]
    zero = np.zeros_like(kx)
    cross = np.stack([np.stack([zero, -kz, ky], -1), np.stack([kz, zero, -kx], -1), np.stack([-ky, kx, zero], -1)],
                     -2)  # fmt: skip
    eye = np.broadcast_to(np.eye(3), cross.shape)
    return eye + np.sin(angle) * cross + (1.0 - np.cos(angle)) * (cross @ cross)


def usable_frames(logs: Sequence[PlateLog]) -> int:
    """How many of the logs' frames a fit uses (those after each log's first :data:`SKIP_S`)."""
    return int(sum(np.count_nonzero(log.frame_t > log.t[0] + SKIP_S) for log in logs))


def _angles(geometry: PlatformGeometry, calibration: ServoCalibration, log: PlateLog,
            servos: Sequence[ServoSpec]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The servos' angles (C, S + 1, 6) rad, untrimmed, under each of the C candidate ``servos`` (one batched run),
    at every physics step of the replay, and their times (S + 1,) s. The replay runs at :data:`SUBSTEPS` physics
    steps a median tick, on a regular grid from the first tick; at each step the servos are sent the pulses of
    the last tick logged by then, so that a late or early tick (a loaded machine's) acts when it was sent."""
    period = float(np.median(np.diff(log.t)))
    hz = int(round(SUBSTEPS / period))
    n = len(servos)
    sim = BatchedSim(geometry, n=n, calibration=calibration, physics_hz=hz, control_hz=hz)
    sim.reset(servo_specs=list(servos))
    steps = int(math.ceil((log.t[-1] + period - log.t[0]) * hz))
    times = log.t[0] + np.arange(steps + 1) / hz
    ticks = np.clip(np.searchsorted(log.t, times[:-1] + 1e-9, side="right") - 1, 0, len(log.t) - 1)
    alpha = np.empty((n, steps + 1, 6))
    alpha[:, 0] = sim.alpha
    for i, k in enumerate(ticks):
        sim.command(np.broadcast_to(log.pulses[k], (n, 6)))
        alpha[:, i + 1] = sim.step_servos()[-1]
    return alpha, times


@one_blas_thread  # its solves and replays are hot loops of matrix products (stewart_gym.blas)
def fit_trims(geometry: PlatformGeometry, calibration: ServoCalibration, logs: Sequence[PlateLog],
              servos: ServoSpec | Sequence[ServoSpec], delay_s: float, plate_top: float) -> TrimFit:  # fmt: skip
    """Fit the trims from ``logs`` (see the module's description).

    Args:
        geometry, calibration: the platform and the calibration the logs ran with.
        logs: the logs with plate poses (:data:`MIN_FRAMES` usable frames or more in all, else
            :class:`~stewart_gym.errors.ConfigError`).
        servos: the servos to replay the pulses with (speed and dead band; no trim), or candidates, the likeliest
            first: the fit starts from the first and keeps the one whose plate poses fit the camera's best.
        delay_s: the first guess of τ (the ball's fitted total latency).
        plate_top: m, the marker plane's height above the platform frame's origin.
    """
    from scipy.optimize import least_squares

    candidates = [servos] if isinstance(servos, ServoSpec) else list(servos)
    if not candidates:
        raise ValueError("fit_trims needs at least one candidate servo")
    parts = []
    for log in logs:
        alpha, times = _angles(geometry, calibration, log, candidates)
        keep = log.frame_t > log.t[0] + SKIP_S
        parts.append((alpha, times, log.frame_t[keep], log.frame_pose[keep]))
    frames = sum(len(p[2]) for p in parts)
    if frames < MIN_FRAMES:
        raise ConfigError(f"the logs hold {frames} camera frames of the plate after their first second; the trims "
                          f"need {MIN_FRAMES} or more: run identify --sensor camera longer")  # fmt: skip
    measured = np.concatenate([rotation_from_vector(pose[:, :3]) @ POINTS.T + pose[:, 3:, None]
                               for _, _, _, pose in parts]).transpose(0, 2, 1)  # (F, 4, 3)  # fmt: skip
    gain = calibration.direction * calibration.us_per_rad
    plate_points = POINTS + np.array([0.0, 0.0, plate_top])
    first = parts[0][3][0]
    camera0 = rotation_from_vector(first[:3])  # the plate near level at the start: the camera's rotation, nearly
    base = np.asarray(geometry.home_position, dtype=np.float64)
    home = base + np.array([0.0, 0.0, plate_top])
    x0 = np.zeros(13)
    x0[9:12] = np.mean(np.concatenate([p[3][:, 3:] for p in parts]), axis=0) - camera0 @ home
    x0[12] = delay_s

    def model(x: np.ndarray, c: int, stride: int = 1) -> np.ndarray:
        """The marker plane's points (F, 4, 3) in the camera's frame for the parameters ``x``, candidate ``c`` (of
        every ``stride``-th frame of each log)."""
        trims, turn, shift, delay = x[:6], x[6:9], x[9:12], x[12]
        out = []
        for alpha, times, frame_t, _ in parts:
            at = frame_t[::stride] - delay
            theta = np.stack([np.interp(at, times, alpha[c, :, i]) for i in range(6)], axis=1) - trims / gain
            pose = forward_kinematics(geometry, servo_angles=theta).pose
            rot = rotation_matrix(pose[:, 3], pose[:, 4], pose[:, 5])
            out.append(plate_points @ rot.transpose(0, 2, 1) + pose[:, None, :3] + base)
        world = np.concatenate(out)
        camera = camera0 @ rotation_from_vector(turn)
        return world @ camera.T + shift

    def residuals(x: np.ndarray, c: int, weight: np.ndarray, stride: int = 1) -> np.ndarray:
        sel = slice(None) if stride == 1 else every(stride)  # the solver's calls: no copy of every frame
        r = (model(x, c, stride) - measured[sel]) * weight[sel, None, None]
        return np.where(np.isfinite(r), r, 0.1).ravel()  # a pose the kinematics cannot close: far off

    def every(stride: int) -> np.ndarray:
        """The indices of every ``stride``-th frame of each log among all the frames."""
        starts = np.cumsum([0, *(len(p[2]) for p in parts)])
        return np.concatenate([np.arange(a, b, stride) for a, b in zip(starts[:-1], starts[1:])])

    scale = np.concatenate([np.full(6, 10.0), np.full(3, 0.01), np.full(3, 0.01), [0.01]])

    def solve(x: np.ndarray, c: int, weight: np.ndarray) -> Any:
        return least_squares(residuals, x, x_scale=scale, loss="soft_l1", f_scale=LOSS_SCALE_M, args=(c, weight))

    def from_start(c: int) -> tuple[Any, np.ndarray, float]:
        """Candidate ``c`` solved from the first guess: unweighted, then with the timing weights its residuals
        give; the solution, the weights and the timing scatter."""
        first = solve(x0, c, np.ones(frames))
        weight, timing_s = _jitter_weights(first.fun.reshape(frames, -1), _point_speed(model, first.x, c))
        return solve(first.x, c, weight), weight, timing_s

    sol, weight, timing_s = from_start(0)
    best, tried, ranked = 0, {0}, list(range(len(candidates)))
    for _ in range(MAX_PICKS if len(candidates) > 1 else 0):
        raw = _unscaled_jacobian(sol.jac, sol.fun)
        stride = RANK_STRIDE if len(ranked) > SHORTLIST else 1  # many candidates: a first cut on fewer frames
        per_frame = raw.shape[0] // frames  # residuals per frame: 4 points × 3 coordinates
        rows = (every(stride)[:, None] * per_frame + np.arange(per_frame)).ravel()
        costs = np.array([_linearised_cost(residuals(sol.x, c, weight, stride), raw[rows]) for c in ranked])
        ranked = [ranked[i] for i in np.argsort(costs)[:SHORTLIST]]  # the next rounds rank only these
        if stride > 1:
            raw_costs = [_linearised_cost(residuals(sol.x, c, weight), raw) for c in ranked]
            ranked = [ranked[i] for i in np.argsort(raw_costs)]
        pick = ranked[0]
        if pick == best or pick in tried:  # settled (or going round): keep the one solved last
            break
        best = pick
        tried.add(pick)
        sol = solve(sol.x, best, weight)
    if best != 0:  # solved from another candidate's solution, with its weights: also from the start with its own,
        fresh, _, fresh_timing = from_start(best)  # and keep the one the frames fit better
        ones = np.ones(frames)
        if _soft_l1_cost(residuals(fresh.x, best, ones)) < _soft_l1_cost(residuals(sol.x, best, ones)):
            sol, timing_s = fresh, fresh_timing
    seconds = np.concatenate([np.floor(p[2] - p[2][0]) + 1e6 * i for i, p in enumerate(parts) if len(p[2])])
    sigma = _grouped_sigma(sol.jac, sol.fun, seconds)
    rms = float(math.sqrt(np.mean(residuals(sol.x, best, np.ones(frames)) ** 2)))
    return TrimFit(sol.x[:6].copy(), sigma[:6], float(sol.x[12]), rms, frames, candidates[best], timing_s)


def _point_speed(model: Any, x: np.ndarray, c: int) -> np.ndarray:
    """m/s: how fast each frame's points move in the model, the root mean square over their coordinates (the
    delay moved by ±5 ms): a frame whose time is off by δt is off by this times δt, coordinate by coordinate."""
    h = 0.005
    early, late = x.copy(), x.copy()
    early[12] -= h
    late[12] += h
    step = model(late, c) - model(early, c)
    step = step.reshape(len(step), -1)
    return np.sqrt(np.nanmean(step**2, axis=1)) / (2 * h)


def _jitter_weights(res: np.ndarray, speed: np.ndarray) -> tuple[np.ndarray, float]:
    """Each frame's weight (F,) and the frames' timing scatter (s): a frame's squared error is taken as the
    camera's noise plus its speed times a timing scatter, squared (a frame's time is known only to a part of a
    frame period), both fitted to the residuals ``res`` (F, k); the weight makes every frame's error the same."""
    from scipy.optimize import nnls

    msq = np.nan_to_num(np.mean(res**2, axis=1), nan=0.0)
    speed = np.nan_to_num(speed, nan=0.0)
    A = np.stack([np.ones_like(speed), speed**2], axis=1)
    coef, _ = nnls(A, msq)
    noise = max(float(coef[0]), 1e-12)
    return np.sqrt(noise / (noise + coef[1] * speed**2)), float(math.sqrt(coef[1]))


def _unscaled_jacobian(jac: np.ndarray, res: np.ndarray) -> np.ndarray:
    """The residuals' own Jacobian from the one ``least_squares`` returns at a solution whose residuals are
    ``res``: it scales each row by the square root of the soft-L1 loss's second derivative, (1 + z)^-3/4 with
    z = (r / scale)², which is undone here."""
    return jac / ((1.0 + (res / LOSS_SCALE_M) ** 2) ** -0.75)[:, None]


def _linearised_cost(res: np.ndarray, jac: np.ndarray) -> float:
    """The soft-L1 cost of residuals ``res`` once the parameters take one (reweighted) Gauss–Newton step with
    the residuals' Jacobian ``jac``."""
    root = (1.0 + (res / LOSS_SCALE_M) ** 2) ** -0.25  # the square root of the loss's weight on each residual
    step = np.linalg.lstsq(jac * root[:, None], -res * root, rcond=None)[0]
    return _soft_l1_cost(res + jac @ step)


def _soft_l1_cost(res: np.ndarray) -> float:
    """The soft-L1 cost of residuals ``res`` (m) at the scale :data:`LOSS_SCALE_M`, as ``least_squares`` counts it."""
    return float(np.sum(2.0 * (np.sqrt(1.0 + (res / LOSS_SCALE_M) ** 2) - 1.0)))


def _grouped_sigma(jac: np.ndarray, res: np.ndarray, group: np.ndarray) -> np.ndarray:
    """One-sigma uncertainties of the parameters: the least-squares covariance with the residuals grouped by
    ``group`` (one value per frame: the log and the second it was taken in), the sandwich estimator, so that
    correlated errors are not counted as independent."""
    per_frame = res.size // len(group)
    groups = np.repeat(group.astype(np.int64), per_frame)
    bread = np.linalg.pinv(jac.T @ jac)
    meat = np.zeros_like(bread)
    for g in np.unique(groups):
        sel = groups == g
        s = jac[sel].T @ res[sel]
        meat += np.outer(s, s)
    return np.sqrt(np.clip(np.diag(bread @ meat @ bread), 0.0, None))
