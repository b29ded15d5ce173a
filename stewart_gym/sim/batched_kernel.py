"""The batched simulator's control period as one compiled loop over the platforms (numba), where numba is installed.

:func:`advance` does for each platform what :meth:`BatchedSim.step <stewart_gym.sim.batched.BatchedSim.step>`'s
NumPy path does for all at once: the servos' physics steps, the plate frames that close the six chains (the chord
method from the period's first frame), and the ball rolling on the moving plate. It takes the servos' targets for
each physics step, which :func:`held_targets` finds first from the commands sent (their lag and dead band). The
platforms' numbers stay in registers and small scratch arrays instead of (N, …) temporaries, and the plates of
:data:`LANES` platforms are solved together, so that the compiler makes that part vector arithmetic: at N = 4,096 a
period costs about an eighth of the NumPy path's time (``bench/bench_batched.py``). The two agree to rounding, and
a platform's numbers do not depend on the others' (``tests/sim/test_batched_kernel.py``).

Without numba (:mod:`stewart_gym.compiled`) :data:`AVAILABLE` is False and the simulator uses its NumPy path.
"""

from __future__ import annotations

import math

import numpy as np

from stewart_gym.compiled import AVAILABLE, compiled

__all__ = ["AVAILABLE", "LANES", "advance", "held_targets"]

# the series' coefficients as products, not divisions (a division costs several multiplications)
_1_6, _1_12, _1_20, _1_24, _1_30, _1_42, _1_56, _1_72 = (1.0 / k for k in (6, 12, 20, 24, 30, 42, 56, 72))


def _tips(cosines: np.ndarray, sines: np.ndarray, j: int, base: np.ndarray, horn: float, cos_beta: np.ndarray,
          sin_beta: np.ndarray, out: np.ndarray) -> None:  # fmt: skip  # pragma: no cover - compiled
    """Horn tips (6, 3) into ``out`` for the servo angles of cosines ``cosines[j]`` and sines ``sines[j]``."""
    for k in range(6):
        ca = horn * cosines[j, k]
        out[k, 0] = base[k, 0] + ca * cos_beta[k]
        out[k, 1] = base[k, 1] + ca * sin_beta[k]
        out[k, 2] = base[k, 2] + horn * sines[j, k]


def _turn(c: float, s: float, d: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """(cos, sin) of an angle turned by ``d`` rad from the angle of cosine ``c`` and sine ``s``: for a servo's
    step (|d| < 0.05) by the series of cos d and sin d, exact to rounding (the next terms are below d¹⁰ / 10!)."""
    if abs(d) < 0.05:
        d2 = d * d
        cd = 1.0 - d2 * 0.5 * (1.0 - d2 * _1_12 * (1.0 - d2 * _1_30 * (1.0 - d2 * _1_56)))
        sd = d * (1.0 - d2 * _1_6 * (1.0 - d2 * _1_20 * (1.0 - d2 * _1_42 * (1.0 - d2 * _1_72))))
    else:
        cd, sd = math.cos(d), math.sin(d)
    return c * cd - s * sd, s * cd + c * sd


def _held_targets(sent_at, sent_pulses, sent_which, delay, since, band, held, trim, home, neutral, per_rad, first_step,
                  out):  # pragma: no cover - compiled
    """The pulses each platform's servos hold over a control period's physics steps, and their target angles.

    For each platform i and each physics step j (``first_step`` + j) of the period (``out`` (s, n, 6)): the latest
    command sent to it since its reset (``since`` (n,)) that its lag (``delay`` (n,) physics steps) has made due is
    taken, servo by servo where it differs from the held pulse by more than the dead band (``band`` (n,) µs), into
    ``held`` (n, 6) µs in place; ``out[j, i]`` is then the angles those pulses give, less the trims (``trim`` (n, 6)
    µs), as :meth:`ServoCalibration.angles <stewart_gym.calibration.ServoCalibration.angles>` finds them (``home``
    rad, ``neutral`` µs and ``per_rad`` µs/rad with its sign, (6,) each). The commands sent are ``sent_at`` (m,) the
    physics step each was sent at, ``sent_pulses`` (m, n, 6) µs and ``sent_which`` (m, n) the platforms each went
    to, oldest first."""
    s, n, m = out.shape[0], out.shape[1], sent_at.shape[0]
    for i in range(n):
        for j in range(s):
            step = first_step + j
            due = -1
            for e in range(m):  # oldest first: the last one due wins
                if sent_which[e, i] and sent_at[e] + delay[i] <= step and sent_at[e] >= since[i]:
                    due = e
            if due >= 0:
                for k in range(6):
                    pulse = sent_pulses[due, i, k]
                    if abs(pulse - held[i, k]) > band[i]:
                        held[i, k] = pulse
            for k in range(6):
                out[j, i, k] = home[k] + (held[i, k] - trim[i, k] - neutral[k]) / per_rad[k]


#: Platforms whose plates :func:`_advance` solves together, a lane each, so that the compiler makes the chains'
#: closing steps vector arithmetic (eight float64 lanes: one AVX-512 register, two AVX2 ones).
LANES = 8


def _advance(targets, alpha, last, gain, max_step, max_change, origin0, rot0, origin1, rot1, xy, v, beta, radius,
             base, horn, cos_beta, sin_beta, anchors, rod, plate_top, gravity, h, newton_steps):  # pragma: no cover
    """One control period of every platform, updating in place the servo angles ``alpha`` (n, 6) and last steps
    ``last`` (n, 6) rad, the platform frames a physics step ago (``origin0`` (n, 3), ``rot0`` (n, 3, 3)) and now
    (``origin1``, ``rot1``), and the balls (``xy``, ``v`` (n, 2)). ``targets`` (s, n, 6) rad: the servos' targets
    over each of the s physics steps of ``h`` s; ``gain``, ``max_step``, ``max_change``, ``beta`` and ``radius``
    (n,): each platform's servos and ball (:class:`~stewart_gym.sim.batched.BatchedSim`); then the build: base
    anchors (6, 3), horn length, the horns' cos β and sin β (6,), platform anchors (6, 3), rod lengths (6,), the
    plate's top; gravity m/s², and the Newton steps per physics step.

    The platforms go :data:`LANES` at a time: each one's servos, horn tips and Jacobian, one by one; then, for all
    of them together, a lane each (every loop of that part runs across the lanes), the Jacobians' LU factors and
    the plates' frames; then each ball. A lane does the operations its platform alone would, in the same order,
    so a platform's numbers do not depend on its neighbours."""
    s, n = targets.shape[0], targets.shape[1]
    cosines, sines = np.empty((s + 1, 6)), np.empty((s + 1, 6))  # of the angles at the start and after each step
    tips, arm = np.empty((6, 3)), np.empty((6, 3))
    pivot, inv_pivot = np.zeros(LANES, dtype=np.int64), np.zeros(LANES)
    # the lanes' numbers, the lane the last axis. The loops over the lanes take only + − × ÷ and √, which give the
    # same bits whether the compiler makes them vector arithmetic or not, but for sin and cos: their loop runs over
    # all LANES lanes in every group (a partial last group's spare lanes compute on what the previous group, or these
    # zeros, left there, and nothing reads them back), so that a vector sin or cos, where the compiler has one,
    # serves every lane the same.
    lane_tips = np.zeros((s, 6, 3, LANES))  # horn tips after each physics step
    lane_lu = np.zeros((6, 6, LANES))  # the Jacobian's LU factors
    lane_order = np.zeros((6, LANES), dtype=np.int64)  # row k of the factored system is row lane_order[k]
    origins, rots = np.zeros((s + 2, 3, LANES)), np.zeros((s + 2, 3, 3, LANES))  # the frames, from a step before
    err, x = np.zeros((6, LANES)), np.zeros((6, LANES))
    theta2, sin_over, cos_over = np.zeros(LANES), np.zeros(LANES), np.zeros(LANES)
    for first in range(0, n, LANES):
        lanes = min(LANES, n - first)
        for b in range(lanes):
            i = first + b
            # the servos
            for k in range(6):
                cosines[0, k], sines[0, k] = math.cos(alpha[i, k]), math.sin(alpha[i, k])
            for k in range(6):
                c, sn = cosines[0, k], sines[0, k]
                for j in range(s):
                    wanted = min(max(gain[i] * (targets[j, i, k] - alpha[i, k]), -max_step[i]), max_step[i])
                    step = min(max(wanted, last[i, k] - max_change[i]), last[i, k] + max_change[i])
                    last[i, k] = step
                    alpha[i, k] += step
                    c, sn = _turn(c, sn, step)
                    cosines[j + 1, k], sines[j + 1, k] = c, sn
            # the chord method's Jacobian at the period's first frame, with the servo angles it started from
            for r in range(3):
                origins[0, r, b], origins[1, r, b] = origin0[i, r], origin1[i, r]
                for col in range(3):
                    rots[0, r, col, b], rots[1, r, col, b] = rot0[i, r, col], rot1[i, r, col]
            _tips(cosines, sines, 0, base, horn, cos_beta, sin_beta, tips)
            for k in range(6):
                for r in range(3):
                    arm[k, r] = (rot1[i, r, 0] * anchors[k, 0] + rot1[i, r, 1] * anchors[k, 1]
                                 + rot1[i, r, 2] * anchors[k, 2])
                d0 = arm[k, 0] + origin1[i, 0] - tips[k, 0]
                d1 = arm[k, 1] + origin1[i, 1] - tips[k, 1]
                d2 = arm[k, 2] + origin1[i, 2] - tips[k, 2]
                length = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                inv = 1.0 / length
                u0, u1, u2 = d0 * inv, d1 * inv, d2 * inv
                lane_lu[k, 0, b], lane_lu[k, 1, b], lane_lu[k, 2, b] = u0, u1, u2
                lane_lu[k, 3, b] = arm[k, 1] * u2 - arm[k, 2] * u1
                lane_lu[k, 4, b] = arm[k, 2] * u0 - arm[k, 0] * u2
                lane_lu[k, 5, b] = arm[k, 0] * u1 - arm[k, 1] * u0
            for j in range(s):
                _tips(cosines, sines, j + 1, base, horn, cos_beta, sin_beta, tips)
                for k in range(6):
                    for r in range(3):
                        lane_tips[j, k, r, b] = tips[k, r]
        # the Jacobians' LU factors, all lanes together, with partial pivoting: the rows' order in lane_order, the
        # multipliers below the diagonal, the pivots' reciprocals on it (the solve multiplies by them)
        for b in range(lanes):
            for k in range(6):
                lane_order[k, b] = k
        for k in range(6):
            for b in range(lanes):
                p, best = k, abs(lane_lu[k, k, b])
                for r in range(k + 1, 6):
                    if abs(lane_lu[r, k, b]) > best:
                        p, best = r, abs(lane_lu[r, k, b])
                pivot[b] = p
            for r in range(k + 1, 6):  # row k and the pivot's row swapped, by selection in each lane
                for col in range(6):
                    for b in range(lanes):
                        here, there = lane_lu[k, col, b], lane_lu[r, col, b]
                        swap = pivot[b] == r
                        lane_lu[k, col, b] = there if swap else here
                        lane_lu[r, col, b] = here if swap else there
                for b in range(lanes):
                    here, there = lane_order[k, b], lane_order[r, b]
                    swap = pivot[b] == r
                    lane_order[k, b] = there if swap else here
                    lane_order[r, b] = here if swap else there
            for b in range(lanes):
                inv_pivot[b] = 1.0 / lane_lu[k, k, b]
            for r in range(k + 1, 6):
                for b in range(lanes):
                    f = lane_lu[r, k, b] * inv_pivot[b]
                    lane_lu[r, k, b] = f
                    for col in range(k + 1, 6):
                        lane_lu[r, col, b] -= f * lane_lu[k, col, b]
            for b in range(lanes):
                lane_lu[k, k, b] = inv_pivot[b]  # the pivot's reciprocal, which the solve multiplies by
        # the plates, all lanes together: each physics step's frame from the period's first, by the chord method
        for j in range(s):
            q = j + 2
            for r in range(3):
                for b in range(lanes):
                    origins[q, r, b] = origins[1, r, b]
                for col in range(3):
                    for b in range(lanes):
                        rots[q, r, col, b] = rots[1, r, col, b]
            for _ in range(newton_steps):
                for k in range(6):  # the rod length errors, negated
                    p0, p1, p2, rod_k = anchors[k, 0], anchors[k, 1], anchors[k, 2], rod[k]
                    for b in range(lanes):
                        d0 = (rots[q, 0, 0, b] * p0 + rots[q, 0, 1, b] * p1 + rots[q, 0, 2, b] * p2 + origins[q, 0, b]
                              - lane_tips[j, k, 0, b])
                        d1 = (rots[q, 1, 0, b] * p0 + rots[q, 1, 1, b] * p1 + rots[q, 1, 2, b] * p2 + origins[q, 1, b]
                              - lane_tips[j, k, 1, b])
                        d2 = (rots[q, 2, 0, b] * p0 + rots[q, 2, 1, b] * p1 + rots[q, 2, 2, b] * p2 + origins[q, 2, b]
                              - lane_tips[j, k, 2, b])
                        err[k, b] = -(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - rod_k)
                # the step x: lu x = err in the factors' row order (lu's diagonal holds the pivots' reciprocals)
                for k in range(6):
                    for b in range(lanes):
                        x[k, b] = err[lane_order[k, b], b]
                for r in range(1, 6):
                    for b in range(lanes):
                        acc = x[r, b]
                        for col in range(r):
                            acc -= lane_lu[r, col, b] * x[col, b]
                        x[r, b] = acc
                for r in range(5, -1, -1):
                    for b in range(lanes):
                        acc = x[r, b]
                        for col in range(r + 1, 6):
                            acc -= lane_lu[r, col, b] * x[col, b]
                        x[r, b] = acc * lane_lu[r, r, b]
                for r in range(3):
                    for b in range(lanes):
                        origins[q, r, b] += x[r, b]
                # rotated by the rotation vector w = x[3:] (Rodrigues): sin θ / θ and (1 − cos θ) / θ² by their
                # series where θ < 0.01, exact to rounding (the next terms are below θ⁸ / 9!)
                for b in range(lanes):
                    t2 = x[3, b] * x[3, b] + x[4, b] * x[4, b] + x[5, b] * x[5, b]
                    theta2[b] = t2
                    sin_over[b] = 1.0 - t2 * _1_6 * (1.0 - t2 * _1_20 * (1.0 - t2 * _1_42))
                    cos_over[b] = 0.5 - t2 * _1_24 * (1.0 - t2 * _1_30 * (1.0 - t2 * _1_56))
                for b in range(LANES):  # all lanes, whatever the group (see the lanes' arrays)
                    if theta2[b] >= 1e-4:
                        theta = math.sqrt(theta2[b])
                        sin_over[b], cos_over[b] = math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta2[b]
                for b in range(lanes):
                    w0, w1, w2, sa, cb = x[3, b], x[4, b], x[5, b], sin_over[b], cos_over[b]
                    c = 1.0 - cb * theta2[b]
                    m00, m01, m02 = c + cb * w0 * w0, cb * w0 * w1 - sa * w2, cb * w0 * w2 + sa * w1
                    m10, m11, m12 = cb * w1 * w0 + sa * w2, c + cb * w1 * w1, cb * w1 * w2 - sa * w0
                    m20, m21, m22 = cb * w2 * w0 - sa * w1, cb * w2 * w1 + sa * w0, c + cb * w2 * w2
                    for col in range(3):
                        r0, r1, r2 = rots[q, 0, col, b], rots[q, 1, col, b], rots[q, 2, col, b]
                        rots[q, 0, col, b] = m00 * r0 + m01 * r1 + m02 * r2
                        rots[q, 1, col, b] = m10 * r0 + m11 * r1 + m12 * r2
                        rots[q, 2, col, b] = m20 * r0 + m21 * r1 + m22 * r2
        for b in range(lanes):  # the balls
            i = first + b
            bt, rad = beta[i], radius[i]
            scale = 1.0 / (1.0 + bt)
            lift = plate_top + rad
            px, py, vx, vy = xy[i, 0], xy[i, 1], v[i, 0], v[i, 1]
            w_prev0 = w_prev1 = w_prev2 = 0.0
            inv_h, inv_hh = 1.0 / h, 1.0 / (h * h)
            for m in range(s + 1):  # the rotation over the half step m + 1/2, over h
                w0 = 0.5 * (rots[m, 1, 0, b] * rots[m + 1, 2, 0, b] - rots[m, 2, 0, b] * rots[m + 1, 1, 0, b]
                            + rots[m, 1, 1, b] * rots[m + 1, 2, 1, b] - rots[m, 2, 1, b] * rots[m + 1, 1, 1, b]
                            + rots[m, 1, 2, b] * rots[m + 1, 2, 2, b] - rots[m, 2, 2, b] * rots[m + 1, 1, 2, b]) * inv_h
                w1 = 0.5 * (rots[m, 2, 0, b] * rots[m + 1, 0, 0, b] - rots[m, 0, 0, b] * rots[m + 1, 2, 0, b]
                            + rots[m, 2, 1, b] * rots[m + 1, 0, 1, b] - rots[m, 0, 1, b] * rots[m + 1, 2, 1, b]
                            + rots[m, 2, 2, b] * rots[m + 1, 0, 2, b] - rots[m, 0, 2, b] * rots[m + 1, 2, 2, b]) * inv_h
                w2 = 0.5 * (rots[m, 0, 0, b] * rots[m + 1, 1, 0, b] - rots[m, 1, 0, b] * rots[m + 1, 0, 0, b]
                            + rots[m, 0, 1, b] * rots[m + 1, 1, 1, b] - rots[m, 1, 1, b] * rots[m + 1, 0, 1, b]
                            + rots[m, 0, 2, b] * rots[m + 1, 1, 2, b] - rots[m, 1, 2, b] * rots[m + 1, 0, 2, b]) * inv_h
                if m > 0:  # physics step j = m − 1: the plate at frame m, between frames m − 1 and m + 1
                    om0, om1, om2 = 0.5 * (w_prev0 + w0), 0.5 * (w_prev1 + w1), 0.5 * (w_prev2 + w2)
                    od0, od1, od2 = (w0 - w_prev0) * inv_h, (w1 - w_prev1) * inv_h, (w2 - w_prev2) * inv_h
                    n0, n1, n2 = rots[m, 0, 2, b], rots[m, 1, 2, b], rots[m, 2, 2, b]
                    push0 = push1 = 0.0
                    k00 = k01 = k10 = k11 = 0.0
                    cr0, cr1, cr2 = od1 * n2 - od2 * n1, od2 * n0 - od0 * n2, od0 * n1 - od1 * n0
                    for r in range(3):
                        ao = (origins[m + 1, r, b] - 2.0 * origins[m, r, b] + origins[m - 1, r, b]) * inv_hh
                        a0 = (rots[m + 1, r, 0, b] - 2.0 * rots[m, r, 0, b] + rots[m - 1, r, 0, b]) * inv_hh
                        a1 = (rots[m + 1, r, 1, b] - 2.0 * rots[m, r, 1, b] + rots[m - 1, r, 1, b]) * inv_hh
                        a2 = (rots[m + 1, r, 2, b] - 2.0 * rots[m, r, 2, b] + rots[m - 1, r, 2, b]) * inv_hh
                        cr = cr0 if r == 0 else (cr1 if r == 1 else cr2)
                        drive = (-gravity if r == 2 else 0.0) - ao - a2 * lift - bt * rad * cr
                        t0, t1 = rots[m, r, 0, b], rots[m, r, 1, b]
                        push0 += t0 * drive
                        push1 += t1 * drive
                        k00 += t0 * a0
                        k01 += t0 * a1
                        k10 += t1 * a0
                        k11 += t1 * a1
                    spin = (om0 * n0 + om1 * n1 + om2 * n2) * ((2.0 + bt) * scale)
                    ax = push0 * scale - (k00 * scale * px + k01 * scale * py) + spin * vy
                    ay = push1 * scale - (k10 * scale * px + k11 * scale * py) - spin * vx
                    vx, vy = vx + ax * h, vy + ay * h
                    px, py = px + vx * h, py + vy * h
                w_prev0, w_prev1, w_prev2 = w0, w1, w2
            xy[i, 0], xy[i, 1], v[i, 0], v[i, 1] = px, py, vx, vy
            for r in range(3):
                origin0[i, r], origin1[i, r] = origins[s, r, b], origins[s + 1, r, b]
                for col in range(3):
                    rot0[i, r, col], rot1[i, r, col] = rots[s, r, col, b], rots[s + 1, r, col, b]


_tips, _turn = (compiled(f) or f for f in (_tips, _turn))
#: :func:`_advance` compiled (None without numba)
advance = compiled(_advance)
#: :func:`_held_targets` compiled (None without numba)
held_targets = compiled(_held_targets)
