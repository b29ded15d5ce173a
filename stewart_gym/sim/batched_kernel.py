"""The batched simulator's control period as one compiled loop over the platforms (numba), where numba is installed.

:func:`advance` does for each platform what :meth:`BatchedSim.step <stewart_gym.sim.batched.BatchedSim.step>`'s
NumPy path does for all at once: the servos' physics steps, the plate frames that close the six chains (the chord
method from the period's first frame), and the ball rolling on the moving plate. It takes the servos' targets for
each physics step, which :func:`held_targets` finds first from the commands sent (their lag and dead band). Each
platform's numbers stay in registers and small scratch arrays instead of (N, …) temporaries: at N = 4,096 a period
costs a fifth of the NumPy path's time (``bench/bench_batched.py``). The two agree to rounding
(``tests/sim/test_batched_kernel.py``).

Without numba (:mod:`stewart_gym.compiled`) :data:`AVAILABLE` is False and the simulator uses its NumPy path.
"""

from __future__ import annotations

import math

import numpy as np

from stewart_gym.compiled import AVAILABLE, compiled

__all__ = ["AVAILABLE", "advance", "held_targets"]

# the series' coefficients as products, not divisions (a division costs several multiplications)
_1_6, _1_12, _1_20, _1_24, _1_30, _1_42, _1_56, _1_72 = (1.0 / k for k in (6, 12, 20, 24, 30, 42, 56, 72))


def _solve6(a: np.ndarray, b: np.ndarray, piv: np.ndarray) -> None:  # pragma: no cover - compiled
    """Solve ``lu x = b`` in place in ``b``, ``a`` being :func:`_factor6`'s factors of a 6 × 6."""
    for k in range(6):
        p = piv[k]
        if p != k:
            b[k], b[p] = b[p], b[k]
    for r in range(1, 6):
        acc = b[r]
        for c in range(r):
            acc -= a[r, c] * b[c]
        b[r] = acc
    for r in range(5, -1, -1):
        acc = b[r]
        for c in range(r + 1, 6):
            acc -= a[r, c] * b[c]
        b[r] = acc * a[r, r]


def _factor6(a: np.ndarray, piv: np.ndarray) -> None:  # pragma: no cover - compiled
    """LU factors of the 6 × 6 ``a`` in place, with partial pivoting (row swaps in ``piv``); the diagonal holds the
    pivots' reciprocals, by which :func:`_solve6` multiplies."""
    for k in range(6):
        p, best = k, abs(a[k, k])
        for r in range(k + 1, 6):
            if abs(a[r, k]) > best:
                p, best = r, abs(a[r, k])
        piv[k] = p
        if p != k:
            for c in range(6):
                a[k, c], a[p, c] = a[p, c], a[k, c]
        inv = 1.0 / a[k, k]
        for r in range(k + 1, 6):
            f = a[r, k] * inv
            a[r, k] = f
            for c in range(k + 1, 6):
                a[r, c] -= f * a[k, c]
        a[k, k] = inv  # the pivot's reciprocal, which the solve multiplies by


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


def _rotate_by(v0: float, v1: float, v2: float, rots: np.ndarray, j: int) -> None:  # pragma: no cover - compiled
    """``rots[j]`` ← Rodrigues(v) @ ``rots[j]`` in place, for a rotation vector v."""
    theta2 = v0 * v0 + v1 * v1 + v2 * v2
    if theta2 < 1e-4:  # θ < 0.01: the series, exact to rounding (the next terms are below θ⁸ / 9!)
        a = 1.0 - theta2 * _1_6 * (1.0 - theta2 * _1_20 * (1.0 - theta2 * _1_42))
        b = 0.5 - theta2 * _1_24 * (1.0 - theta2 * _1_30 * (1.0 - theta2 * _1_56))
    else:
        theta = math.sqrt(theta2)
        a, b = math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta2
    c = 1.0 - b * theta2
    m00, m01, m02 = c + b * v0 * v0, b * v0 * v1 - a * v2, b * v0 * v2 + a * v1
    m10, m11, m12 = b * v1 * v0 + a * v2, c + b * v1 * v1, b * v1 * v2 - a * v0
    m20, m21, m22 = b * v2 * v0 - a * v1, b * v2 * v1 + a * v0, c + b * v2 * v2
    for col in range(3):
        r0, r1, r2 = rots[j, 0, col], rots[j, 1, col], rots[j, 2, col]
        rots[j, 0, col] = m00 * r0 + m01 * r1 + m02 * r2
        rots[j, 1, col] = m10 * r0 + m11 * r1 + m12 * r2
        rots[j, 2, col] = m20 * r0 + m21 * r1 + m22 * r2


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


def _advance(targets, alpha, last, gain, max_step, max_change, origin0, rot0, origin1, rot1, xy, v, beta, radius,
             base, horn, cos_beta, sin_beta, anchors, rod, plate_top, gravity, h, newton_steps):  # pragma: no cover
    """One control period of every platform, updating in place the servo angles ``alpha`` (n, 6) and last steps
    ``last`` (n, 6) rad, the platform frames a physics step ago (``origin0`` (n, 3), ``rot0`` (n, 3, 3)) and now
    (``origin1``, ``rot1``), and the balls (``xy``, ``v`` (n, 2)). ``targets`` (s, n, 6) rad: the servos' targets
    over each of the s physics steps of ``h`` s; ``gain``, ``max_step``, ``max_change``, ``beta`` and ``radius``
    (n,): each platform's servos and ball (:class:`~stewart_gym.sim.batched.BatchedSim`); then the build: base
    anchors (6, 3), horn length, the horns' cos β and sin β (6,), platform anchors (6, 3), rod lengths (6,), the
    plate's top; gravity m/s², and the Newton steps per physics step."""
    s, n = targets.shape[0], targets.shape[1]
    cosines, sines = np.empty((s + 1, 6)), np.empty((s + 1, 6))  # of the angles at the start and after each step
    origins = np.empty((s + 2, 3))
    rots = np.empty((s + 2, 3, 3))
    tips = np.empty((6, 3))
    arm = np.empty((6, 3))
    jac = np.empty((6, 6))
    piv = np.empty(6, dtype=np.int64)
    err = np.empty(6)
    for i in range(n):
        for k in range(6):
            cosines[0, k], sines[0, k] = math.cos(alpha[i, k]), math.sin(alpha[i, k])
        # the servos
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
            origins[0, r], origins[1, r] = origin0[i, r], origin1[i, r]
            for col in range(3):
                rots[0, r, col], rots[1, r, col] = rot0[i, r, col], rot1[i, r, col]
        _tips(cosines, sines, 0, base, horn, cos_beta, sin_beta, tips)
        for k in range(6):
            for r in range(3):
                arm[k, r] = rot1[i, r, 0] * anchors[k, 0] + rot1[i, r, 1] * anchors[k, 1] + rot1[i, r, 2] * anchors[k, 2]
            d0 = arm[k, 0] + origin1[i, 0] - tips[k, 0]
            d1 = arm[k, 1] + origin1[i, 1] - tips[k, 1]
            d2 = arm[k, 2] + origin1[i, 2] - tips[k, 2]
            length = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            inv = 1.0 / length
            u0, u1, u2 = d0 * inv, d1 * inv, d2 * inv
            jac[k, 0], jac[k, 1], jac[k, 2] = u0, u1, u2
            jac[k, 3] = arm[k, 1] * u2 - arm[k, 2] * u1
            jac[k, 4] = arm[k, 2] * u0 - arm[k, 0] * u2
            jac[k, 5] = arm[k, 0] * u1 - arm[k, 1] * u0
        _factor6(jac, piv)
        # the plate: each physics step's frame from the period's first, by the chord method
        for j in range(s):
            _tips(cosines, sines, j + 1, base, horn, cos_beta, sin_beta, tips)
            q = j + 2
            for r in range(3):
                origins[q, r] = origin1[i, r]
                for col in range(3):
                    rots[q, r, col] = rot1[i, r, col]
            for _ in range(newton_steps):
                for k in range(6):
                    p0, p1, p2 = anchors[k, 0], anchors[k, 1], anchors[k, 2]
                    d0 = rots[q, 0, 0] * p0 + rots[q, 0, 1] * p1 + rots[q, 0, 2] * p2 + origins[q, 0] - tips[k, 0]
                    d1 = rots[q, 1, 0] * p0 + rots[q, 1, 1] * p1 + rots[q, 1, 2] * p2 + origins[q, 1] - tips[k, 1]
                    d2 = rots[q, 2, 0] * p0 + rots[q, 2, 1] * p1 + rots[q, 2, 2] * p2 + origins[q, 2] - tips[k, 2]
                    err[k] = -(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - rod[k])
                _solve6(jac, err, piv)
                origins[q, 0] += err[0]
                origins[q, 1] += err[1]
                origins[q, 2] += err[2]
                _rotate_by(err[3], err[4], err[5], rots, q)
        # the ball
        b, rad = beta[i], radius[i]
        scale = 1.0 / (1.0 + b)
        lift = plate_top + rad
        x, y, vx, vy = xy[i, 0], xy[i, 1], v[i, 0], v[i, 1]
        w_prev0 = w_prev1 = w_prev2 = 0.0
        inv_h, inv_hh = 1.0 / h, 1.0 / (h * h)
        for m in range(s + 1):  # the rotation over the half step m + 1/2, over h
            w0 = 0.5 * (rots[m, 1, 0] * rots[m + 1, 2, 0] - rots[m, 2, 0] * rots[m + 1, 1, 0]
                        + rots[m, 1, 1] * rots[m + 1, 2, 1] - rots[m, 2, 1] * rots[m + 1, 1, 1]
                        + rots[m, 1, 2] * rots[m + 1, 2, 2] - rots[m, 2, 2] * rots[m + 1, 1, 2]) * inv_h
            w1 = 0.5 * (rots[m, 2, 0] * rots[m + 1, 0, 0] - rots[m, 0, 0] * rots[m + 1, 2, 0]
                        + rots[m, 2, 1] * rots[m + 1, 0, 1] - rots[m, 0, 1] * rots[m + 1, 2, 1]
                        + rots[m, 2, 2] * rots[m + 1, 0, 2] - rots[m, 0, 2] * rots[m + 1, 2, 2]) * inv_h
            w2 = 0.5 * (rots[m, 0, 0] * rots[m + 1, 1, 0] - rots[m, 1, 0] * rots[m + 1, 0, 0]
                        + rots[m, 0, 1] * rots[m + 1, 1, 1] - rots[m, 1, 1] * rots[m + 1, 0, 1]
                        + rots[m, 0, 2] * rots[m + 1, 1, 2] - rots[m, 1, 2] * rots[m + 1, 0, 2]) * inv_h
            if m > 0:  # physics step j = m − 1: the plate at frame m, between frames m − 1 and m + 1
                om0, om1, om2 = 0.5 * (w_prev0 + w0), 0.5 * (w_prev1 + w1), 0.5 * (w_prev2 + w2)
                od0, od1, od2 = (w0 - w_prev0) * inv_h, (w1 - w_prev1) * inv_h, (w2 - w_prev2) * inv_h
                n0, n1, n2 = rots[m, 0, 2], rots[m, 1, 2], rots[m, 2, 2]
                push0 = push1 = 0.0
                k00 = k01 = k10 = k11 = 0.0
                cr0, cr1, cr2 = od1 * n2 - od2 * n1, od2 * n0 - od0 * n2, od0 * n1 - od1 * n0
                for r in range(3):
                    ao = (origins[m + 1, r] - 2.0 * origins[m, r] + origins[m - 1, r]) * inv_hh
                    a0 = (rots[m + 1, r, 0] - 2.0 * rots[m, r, 0] + rots[m - 1, r, 0]) * inv_hh
                    a1 = (rots[m + 1, r, 1] - 2.0 * rots[m, r, 1] + rots[m - 1, r, 1]) * inv_hh
                    a2 = (rots[m + 1, r, 2] - 2.0 * rots[m, r, 2] + rots[m - 1, r, 2]) * inv_hh
                    cr = cr0 if r == 0 else (cr1 if r == 1 else cr2)
                    drive = (-gravity if r == 2 else 0.0) - ao - a2 * lift - b * rad * cr
                    t0, t1 = rots[m, r, 0], rots[m, r, 1]
                    push0 += t0 * drive
                    push1 += t1 * drive
                    k00 += t0 * a0
                    k01 += t0 * a1
                    k10 += t1 * a0
                    k11 += t1 * a1
                spin = (om0 * n0 + om1 * n1 + om2 * n2) * ((2.0 + b) * scale)
                ax = push0 * scale - (k00 * scale * x + k01 * scale * y) + spin * vy
                ay = push1 * scale - (k10 * scale * x + k11 * scale * y) - spin * vx
                vx, vy = vx + ax * h, vy + ay * h
                x, y = x + vx * h, y + vy * h
            w_prev0, w_prev1, w_prev2 = w0, w1, w2
        xy[i, 0], xy[i, 1], v[i, 0], v[i, 1] = x, y, vx, vy
        for r in range(3):
            origin0[i, r], origin1[i, r] = origins[s, r], origins[s + 1, r]
            for col in range(3):
                rot0[i, r, col], rot1[i, r, col] = rots[s, r, col], rots[s + 1, r, col]


_solve6, _factor6, _tips, _turn, _rotate_by = (compiled(f) or f for f in (_solve6, _factor6, _tips, _turn, _rotate_by))
#: :func:`_advance` compiled (None without numba)
advance = compiled(_advance)
#: :func:`_held_targets` compiled (None without numba)
held_targets = compiled(_held_targets)
