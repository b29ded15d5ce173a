"""The LQR bringing the ball in, the PID holding it: :class:`HandoverController` (``--policy lqr-pid``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stewart_gym.control.arrays import planar_length
from stewart_gym.control.lqr import LQRController, LQRDesign, LQRGains
from stewart_gym.control.parts import EpisodicController, periods_in_a_row, whole_periods
from stewart_gym.control.pid import CascadedPID, PIDGains

__all__ = ["HANDOVER_OPTIONAL", "HANDOVER_SIZES", "PUSH_NOISE_WINDOW_S", "PUSH_SPEED_SIGMAS", "HandoverController",
           "HandoverDesign", "HandoverGains"]

#: The hand-over's own sizes (:class:`HandoverDesign`): the first three positive, the rest 0 (off) or more.
HANDOVER_SIZES = ("handover_mm", "handover_mm_s", "release_mm", "handover_dwell_s", "release_dwell_s", "release_mm_s",
                  "push_release_mm")
#: The sizes that may be 0 (off).
HANDOVER_OPTIONAL = ("handover_dwell_s", "release_dwell_s", "release_mm_s", "push_release_mm")


@dataclass(frozen=True)
class HandoverDesign:
    """The LQR bringing the ball in, the PID holding it (``policies/lqr_pid.json``, ``--policy lqr-pid``).

    The LQR settles fastest and the PID behind the Kalman observer holds the ball tightest and quietest, on a
    still target and, as both feed the target's acceleration forward, on a moving one; this controller runs the
    LQR until the ball is within ``handover_mm`` of the target and slower than ``handover_mm_s`` relative to it,
    then the PID, until the ball is farther than ``release_mm`` (then the LQR again). Under heavy panel noise
    the observed speed seldom falls below ``handover_mm_s`` (8 mm of noise leaves about 20 mm/s in the
    estimate), so once the ball has stayed within ``release_mm`` of the target for ``handover_dwell_s``, the
    PID takes over within ``handover_mm`` whatever the observed speed (0: never). Under the same noise the
    filtered position strays beyond ``release_mm`` now and then while the ball itself is held; with
    ``release_dwell_s`` the LQR takes the ball back only once it has been observed beyond ``release_mm`` that
    long (0: at once), unless it is also faster than ``release_mm_s`` relative to the target: a push, which the
    LQR brings back sooner, more than noise (8 mm of it leaves about 20 mm/s of error in the filtered speed; 0:
    no exception). A push that leaves the ball within ``release_mm`` is caught by ``push_release_mm``: while the
    PID holds, a ball beyond it that moves faster than ``release_mm_s`` and than :data:`PUSH_SPEED_SIGMAS` times
    the RMS speed observed during the hold (over about :data:`PUSH_NOISE_WINDOW_S`; what the panel's noise
    leaves in the estimate, so a noisy panel needs a harder push) goes back to the LQR at once. The PID takes over
    with its own integral, which it has kept within
    its integration zone all along (loading it with the LQR's integral term instead carried over a transient:
    after a fast approach the ball could drift out of the success radius for seconds).

    Attributes:
        lqr: the LQR's design.
        pid: the PID's gains.
        handover_mm, handover_mm_s: the PID takes over within this distance of the target and below this speed
            relative to it.
        release_mm: the LQR takes back beyond this distance (more than ``handover_mm``).
        handover_dwell_s: after this long within ``release_mm`` the speed no longer matters (0: it always does).
        release_dwell_s: the LQR takes back after this long beyond ``release_mm`` (0: at once).
        release_mm_s: with a release dwell, the LQR takes back at once a ball beyond ``release_mm`` that moves
            faster than this relative to the target (0: never).
        push_release_mm: within ``release_mm``, the LQR takes back at once a ball beyond this distance that moves
            faster than ``release_mm_s`` and than the noise allows (above; 0: never; less than ``release_mm``).
    """

    lqr: LQRDesign
    pid: PIDGains
    handover_mm: float = 2.0
    handover_mm_s: float = 10.0
    release_mm: float = 20.0
    handover_dwell_s: float = 0.0
    release_dwell_s: float = 0.0
    release_mm_s: float = 0.0
    push_release_mm: float = 0.0


@dataclass(frozen=True)
class HandoverGains:
    """A designed :class:`HandoverController` (what a bundle stores): the LQR's gains, the PID's gains (both for
    one geometry), the tilt at action ±1, the hand-over sizes and the control period."""

    lqr: LQRGains
    pid: PIDGains
    max_tilt: float
    handover_mm: float
    handover_mm_s: float
    release_mm: float
    dt: float
    handover_dwell_s: float = 0.0  # after the others: bundles written before it load without it
    release_dwell_s: float = 0.0  # likewise
    release_mm_s: float = 0.0  # likewise
    push_release_mm: float = 0.0  # likewise


#: :attr:`HandoverDesign.push_release_mm`: a push is faster than this many times the RMS speed observed while the
#: PID holds, which is averaged over about this many seconds of holding (from ``handover_mm_s``, the speed the PID
#: takes over below, at the start of an episode; kept while the LQR has the ball, as the noise is the same).
PUSH_SPEED_SIGMAS = 3.0
PUSH_NOISE_WINDOW_S = 1.0


class HandoverController(EpisodicController):
    """A policy: observation (…, 12) → tilt action (…, 2): the LQR far from the target, the PID near it
    (:class:`HandoverDesign`). Both run every period (each keeps its state); one row per ball in a batch."""

    def __init__(self, gains: HandoverGains, plate_half: tuple[float, float] = (0.15, 0.15)) -> None:
        super().__init__(plate_half)
        self.gains = gains
        self.lqr = LQRController(gains.lqr, plate_half)
        self.pid = CascadedPID(gains.pid, gains.dt, plate_half)
        self.reset()

    def reset(self, rows: np.ndarray | None = None) -> None:
        """Start of an episode: the LQR is in control (of every row, or of the rows of the boolean mask ``rows``)."""
        self.lqr.reset(rows)
        self.pid.reset(rows)
        near = getattr(self, "_near", None)
        if rows is not None and near is not None and near.shape == np.shape(rows):
            near[rows] = False
            for count in (self._inside, self._beyond):
                if count is not None:
                    count[rows] = 0
            if self._held_speed2 is not None:
                self._held_speed2[rows] = self.gains.handover_mm_s**2
            return
        self._near: np.ndarray | None = None
        self._inside: np.ndarray | None = None  # periods each ball has been within release_mm of the target
        self._beyond: np.ndarray | None = None  # periods each ball has been observed beyond release_mm
        self._held_speed2: np.ndarray | None = None  # (mm/s)²: mean square speed observed while the PID holds

    @property
    def pid_in_control(self) -> np.ndarray | None:
        """Whether the PID holds each row (None before the first observation)."""
        return None if self._near is None else self._near.copy()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        g = self.gains
        o = np.asarray(obs, dtype=np.float64)
        by_lqr = self.lqr(o)
        pos, vel, target, target_vel = self.observation.motion(o)
        distance_mm = planar_length(target - pos) * 1e3
        speed_mm_s = planar_length(vel - target_vel) * 1e3
        fresh = self._near is None or self._near.shape != distance_mm.shape
        near = np.zeros(distance_mm.shape, dtype=bool) if fresh else self._near
        self._inside = periods_in_a_row(None if fresh else self._inside, distance_mm <= g.release_mm)
        slow = speed_mm_s < g.handover_mm_s
        if g.handover_dwell_s > 0:  # whole periods: 3 s at 50 Hz is the 150th
            slow |= self._inside >= whole_periods(g.handover_dwell_s, g.dt)
        enter = ~near & (distance_mm < g.handover_mm) & slow
        self._beyond = periods_in_a_row(None if fresh else self._beyond, distance_mm > g.release_mm)
        gone = self._beyond >= max(1, whole_periods(g.release_dwell_s, g.dt))  # 0 s: the first period beyond
        if g.release_mm_s > 0:  # a push, not noise: the LQR takes back at once
            gone |= (distance_mm > g.release_mm) & (speed_mm_s > g.release_mm_s)
        if g.push_release_mm > 0:  # a push within release_mm: faster than the noise lets the held ball seem
            held2 = self._held_speed2
            if fresh or held2 is None:
                held2 = np.full(distance_mm.shape, g.handover_mm_s**2)
            limit = np.maximum(g.release_mm_s, PUSH_SPEED_SIGMAS * np.sqrt(held2))
            gone |= near & (distance_mm > g.push_release_mm) & (speed_mm_s > limit)
            weight = min(1.0, g.dt / PUSH_NOISE_WINDOW_S)
            self._held_speed2 = np.where(near, held2 + weight * (speed_mm_s * speed_mm_s - held2), held2)
        self._near = (near | enter) & ~gone
        by_pid = self.pid(o)
        return np.where(self._near[..., None], by_pid, by_lqr).astype(np.float32)
