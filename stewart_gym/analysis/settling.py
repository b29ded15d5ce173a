"""A lower bound on how fast any controller can settle the ball: :func:`fastest_settling`, a linear program
over the LQR's linear model of the ball on the lagging plate."""

from __future__ import annotations

import math

import numpy as np

from stewart_gym.actions import DEFAULT_MAX_TILT
from stewart_gym.control.lqr import LQRDesign, lqr_model

__all__ = ["fastest_settling"]


def fastest_settling(start: tuple[float, float], radius: float, max_tilt: float = DEFAULT_MAX_TILT,
                     design: LQRDesign | None = None, dt: float = 0.02, hold_s: float = 0.8,
                     sides: int = 16) -> float:  # fmt: skip
    """s: a lower bound on the settling time from rest at ``start`` (x, y, m from the target) under the LQR's
    linear model (:func:`lqr_model` of ``design``: the rolling ball, one control period of dead time, the tilt's
    lag, the command held for ``dt``), each axis' tilt within ±``max_tilt``: the fewest periods N such that some
    command sequence keeps the ball within ``radius`` (a ``sides``-gon inside that circle) from period N on for
    ``hold_s`` more and leaves it at rest. Each N is a linear program (scipy's HiGHS), N found by bisection
    (a sequence that settles by N settles by N + 1). The simulator adds
    what the model leaves out (the ball's first push away from the target as the plate starts to turn, rolling
    friction, the servos' speed limit), so no controller there reaches this bound; it tells how far one is
    from it."""
    from scipy.optimize import linprog

    d = design or LQRDesign()
    a4 = lqr_model(d, dt)[0][:4, :4]  # (p, v, a, u in flight); the new command enters as u in flight
    limit, hold = math.sin(max_tilt), max(1, round(hold_s / dt))

    def feasible(n: int) -> bool:
        periods = n + hold
        rows, bounds_ub = [], []
        free = [np.array([p0, 0.0, 0.0, 0.0]) for p0 in start]  # each axis' state with no command
        gain = [np.zeros((4, periods)) for _ in start]  # … and its response to each command
        for k in range(periods + 1):
            if k >= n:
                for i in range(sides):
                    cx, cy = math.cos(2 * math.pi * i / sides), math.sin(2 * math.pi * i / sides)
                    rows.append(np.concatenate([cx * gain[0][0], cy * gain[1][0]]))
                    bounds_ub.append(radius * math.cos(math.pi / sides) - cx * free[0][0] - cy * free[1][0])
            if k == periods:
                break
            for axis in range(2):
                free[axis], gain[axis] = a4 @ free[axis], a4 @ gain[axis]
                gain[axis][3, k] += 1.0  # the command sent at period k is in flight during period k + 1
        none = np.zeros(periods)  # at rest at the end: each axis' velocity from its own commands
        at_rest = np.array([np.concatenate([gain[0][1], none]), np.concatenate([none, gain[1][1]])])
        result = linprog(np.zeros(2 * periods), A_ub=np.array(rows), b_ub=np.array(bounds_ub), A_eq=at_rest,
                         b_eq=[-free[0][1], -free[1][1]], bounds=[(-limit, limit)] * (2 * periods),
                         method="highs")  # fmt: skip
        return bool(result.status == 0)

    low, high = 0, 1  # settles by high, not by low − 1
    while not feasible(high):
        low, high = high + 1, 2 * high
    while low < high:
        mid = (low + high) // 2
        low, high = (low, mid) if feasible(mid) else (mid + 1, high)
    return high * dt
