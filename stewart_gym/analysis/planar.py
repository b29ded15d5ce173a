"""Forward kinematics of the planar 3-RPR platform (source 004; Sauer, *Numerical Analysis*, Reality Check 1).

Base anchors at (0, 0), (x1, 0), (x2, y2). The moving triangle has its first
vertex at (x, y); side L3 leaves it at angle θ and side L2 at angle θ + γ; L1 is
the side opposite. Struts p1, p2, p3 join the anchors to the three vertices.
Every pose is a root of

    f(θ) = N1² + N2² − p1² D²

with A2 = L3 cos θ − x1, B2 = L3 sin θ, A3 = L2 cos(θ + γ) − x2,
B3 = L2 sin(θ + γ) − y2, D = 2 (A2 B3 − B2 A3),
N1 = B3 (p2² − p1² − A2² − B2²) − B2 (p3² − p1² − A3² − B3²),
N2 = −A3 (p2² − p1² − A2² − B2²) + A2 (p3² − p1² − A3² − B3²),
x = N1 / D, y = N2 / D. (The seed prints ``p_3^2-p_1^2A_3^2-B_3^2``: the
intended term is p3² − p1² − A3² − B3²; the docs: Sources, errata.)

:func:`solve_planar` finds **all** roots on [−π, π]: it brackets every sign
change of f on a fine grid and refines it, and it finds tangential (double)
roots, where f touches zero without changing sign, as local minima of |f|.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from stewart_gym.checks import finite_array, real_number
from stewart_gym.errors import ConfigError
from stewart_gym.progress import Progress

__all__ = ["PLANAR_KEYS", "PLANAR_PRESETS", "planar_continua", "planar_f", "planar_struts", "planar_vertices",
           "solve_planar", "sweep_strut"]

#: 3-RPR parameter sets from Sauer's Reality Check 1 (the seed's source).
PLANAR_PRESETS: dict[str, dict[str, float]] = {
    "sauer-test": {"L1": 2.0, "L2": math.sqrt(2), "L3": math.sqrt(2), "gamma": math.pi / 2, "x1": 4.0, "x2": 0.0,
                   "y2": 4.0, "p1": math.sqrt(5), "p2": math.sqrt(5), "p3": math.sqrt(5)},
    "sauer": {"L1": 3.0, "L2": 3 * math.sqrt(2), "L3": 3.0, "gamma": math.pi / 4, "x1": 5.0, "x2": 0.0, "y2": 6.0,
              "p1": 5.0, "p2": 5.0, "p3": 3.0},
}  # fmt: skip
PLANAR_KEYS = ("L1", "L2", "L3", "gamma", "x1", "x2", "y2", "p1", "p2", "p3")
#: The fewest θ samples :func:`solve_planar` takes (one a degree): fewer miss roots that lie close together (on
#: Sauer's sets, 10 samples already lose two of the six poses at p2 = 7).
MIN_PLANAR_SAMPLES = 360



def _offsets(theta: np.ndarray, L2: float, L3: float, gamma: float, x1: float, x2: float, y2: float, p1: float,
             p2: float, p3: float) -> tuple[np.ndarray, ...]:  # fmt: skip
    """At angles θ: (A2, B2) and (A3, B3), the offsets of the second and third vertex from their anchors less the
    first vertex, and the right sides u and v: with the first vertex at w, the struts ask |w| = p1,
    2 (A2, B2)·w = u and 2 (A3, B3)·w = v."""
    a2 = L3 * np.cos(theta) - x1
    b2 = L3 * np.sin(theta)
    a3 = L2 * np.cos(theta + gamma) - x2
    b3 = L2 * np.sin(theta + gamma) - y2
    return a2, b2, a3, b3, p2**2 - p1**2 - a2**2 - b2**2, p3**2 - p1**2 - a3**2 - b3**2


def _terms(theta: np.ndarray, *args: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """N1, N2 and D at angles θ (the linear equations solved by Cramer's rule: x = N1 / D, y = N2 / D)."""
    a2, b2, a3, b3, u, v = _offsets(theta, *args)
    return b3 * u - b2 * v, -a3 * u + a2 * v, 2.0 * (a2 * b3 - b2 * a3)


def planar_f(theta: np.ndarray | float, L1: float, L2: float, L3: float, gamma: float, x1: float, x2: float,
             y2: float, p1: float, p2: float, p3: float) -> np.ndarray:  # fmt: skip
    """f(θ) = N1² + N2² − p1² D², vectorised over θ (rad)."""
    n1, n2, d = _terms(np.asarray(theta, dtype=np.float64), L2, L3, gamma, x1, x2, y2, p1, p2, p3)
    return n1**2 + n2**2 - p1**2 * d**2


def planar_vertices(pose: np.ndarray, L2: float, L3: float, gamma: float) -> np.ndarray:
    """The triangle's vertices (…, 3, 2) for poses (…, 3) = (x, y, θ)."""
    pose = np.asarray(pose, dtype=np.float64)
    x, y, th = pose[..., 0], pose[..., 1], pose[..., 2]
    v1 = np.stack([x, y], -1)
    v2 = np.stack([x + L3 * np.cos(th), y + L3 * np.sin(th)], -1)
    v3 = np.stack([x + L2 * np.cos(th + gamma), y + L2 * np.sin(th + gamma)], -1)
    return np.stack([v1, v2, v3], -2)


def planar_struts(pose: np.ndarray, L2: float, L3: float, gamma: float, x1: float, x2: float, y2: float) -> np.ndarray:
    """Strut lengths (…, 3) of poses (…, 3): the inverse kinematics."""
    verts = planar_vertices(pose, L2, L3, gamma)
    anchors = np.array([[0.0, 0.0], [x1, 0.0], [x2, y2]])
    return np.linalg.norm(verts - anchors, axis=-1)


def solve_planar(L1: float, L2: float, L3: float, gamma: float, x1: float, x2: float, y2: float, p1: float,
                 p2: float, p3: float, *, samples: int = 4000, tol: float = 1e-9) -> np.ndarray:  # fmt: skip
    """All poses (x, y, θ) with the given strut lengths: array (k, 3) sorted by θ; k = 0 when there is none.

    Each candidate θ is kept only if the pose it gives reproduces the three strut
    lengths to ``tol`` (relative to the largest strut). Where D = 0 at a root the
    two linear equations are one: the poses at that θ are where its line meets the
    first strut's circle (none, one or two). Where both vanish (the moving triangle
    is the base triangle turned by θ, and p1 = p2 = p3) every point of that circle
    is a pose: :func:`planar_continua` gives those θ, which this leaves out.
    ``L1`` must be the side the law of cosines gives from L2, L3 and γ.
    """
    real_number("samples", samples, whole=True, low=MIN_PLANAR_SAMPLES)
    real_number("tol", tol, low=0, low_open=True)
    for name, v in (("L1", L1), ("L2", L2), ("L3", L3), ("p1", p1), ("p2", p2), ("p3", p3)):
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"{name} must be a positive, finite length, got {v}")
    for name, v in (("gamma", gamma), ("x1", x1), ("x2", x2), ("y2", y2)):
        if not math.isfinite(v):
            raise ConfigError(f"{name} must be finite, got {v}")
    opposite = math.sqrt(max(0.0, L2 * L2 + L3 * L3 - 2.0 * L2 * L3 * math.cos(gamma)))
    if abs(L1 - opposite) > 1e-6 * max(L1, L2, L3):
        raise ConfigError(f"L1 is the side opposite the angle gamma: L2 = {L2:g}, L3 = {L3:g} and gamma = {gamma:g} "
                          f"rad make it {opposite:.9g}, not {L1:g}; give L1 = {opposite:.9g} (or change L2, L3 or "
                          "gamma)")  # fmt: skip
    args = (L1, L2, L3, gamma, x1, x2, y2, p1, p2, p3)

    def f(t: float) -> float:
        return float(planar_f(t, *args))

    grid = np.linspace(-math.pi, math.pi, samples + 1)
    vals = planar_f(grid, *args)
    scale = float(np.max(np.abs(vals))) or 1.0
    roots: list[float] = []
    exact = np.flatnonzero(vals == 0.0)
    roots += grid[exact].tolist()
    sign_change = np.flatnonzero(np.sign(vals[:-1]) * np.sign(vals[1:]) < 0)
    roots += [brentq(f, grid[i], grid[i + 1], xtol=1e-15, rtol=1e-15, maxiter=200) for i in sign_change]
    # tangential roots: local minima of |f| that do not change sign
    mag = np.abs(vals)
    minima = np.flatnonzero((mag[1:-1] <= mag[:-2]) & (mag[1:-1] <= mag[2:])) + 1
    for i in minima:
        if np.sign(vals[i - 1]) * np.sign(vals[i + 1]) < 0:
            continue  # already bracketed
        res = minimize_scalar(lambda t: abs(f(t)), bounds=(grid[i - 1], grid[i + 1]), method="bounded",
                              options={"xatol": 1e-13})  # fmt: skip
        if abs(f(res.x)) <= 1e-10 * scale:
            roots.append(float(res.x))
    poses: list[np.ndarray] = []
    strut_scale = max(p1, p2, p3)
    for th in sorted(roots):
        n1, n2, d = _terms(np.array(th), L2, L3, gamma, x1, x2, y2, p1, p2, p3)
        if abs(float(d)) >= 1e-12 * (1 + strut_scale**2):
            candidates = [np.array([float(n1 / d), float(n2 / d), float(th)])]
        else:  # one line, or none (a continuum: planar_continua), where D = 0
            candidates = [np.array([x, y, th]) for x, y in _line_and_circle(th, L2, L3, gamma, x1, x2, y2, p1, p2, p3)]
        for pose in candidates:
            struts = planar_struts(pose, L2, L3, gamma, x1, x2, y2)
            if np.max(np.abs(struts - [p1, p2, p3])) <= max(tol, 1e-6) * strut_scale and not any(
                    _same_pose(pose, other, strut_scale) for other in poses):  # fmt: skip
                poses.append(pose)
    return np.array(poses).reshape(-1, 3)


def _same_pose(a: np.ndarray, b: np.ndarray, scale: float) -> bool:
    """Whether poses ``a`` and ``b`` are one (θ = −π and θ = π are the same angle)."""
    turn = abs(((a[2] - b[2] + math.pi) % (2 * math.pi)) - math.pi)
    return turn <= 1e-7 and abs(a[0] - b[0]) <= 1e-7 * scale and abs(a[1] - b[1]) <= 1e-7 * scale


def _line_and_circle(theta: float, *args: float) -> list[tuple[float, float]]:
    """Where D = 0 at θ (e2 ∥ e3): the first vertex's points on the line of the larger of e2 and e3 and on the
    first strut's circle; none where both offsets vanish."""
    a2, b2, a3, b3, u, v = (float(x) for x in _offsets(np.array(theta), *args))
    e2, e3 = np.array([a2, b2]), np.array([a3, b3])
    e, c = (e2, u / 2) if e2 @ e2 >= e3 @ e3 else (e3, v / 2)
    norm2, p1 = float(e @ e), args[7]
    if norm2 <= 1e-24 * (1.0 + p1 * p1):
        return []
    foot = e * (c / norm2)
    half2 = p1 * p1 - float(foot @ foot)
    if half2 < -1e-12 * p1 * p1:
        return []
    along = np.array([-e[1], e[0]]) / math.sqrt(norm2) * math.sqrt(max(half2, 0.0))
    return [(float(foot[0] + s * along[0]), float(foot[1] + s * along[1])) for s in (-1.0, 1.0)]


def planar_continua(L1: float, L2: float, L3: float, gamma: float, x1: float, x2: float, y2: float, p1: float,
                    p2: float, p3: float) -> list[float]:  # fmt: skip
    """The angles θ (rad, in (−π, π]) at which the platform has a continuum of poses: the moving triangle is the
    base triangle turned by θ (each vertex offset from its anchor as the first from its own) and the three struts
    are equally long, so that the first vertex may be anywhere on the circle of radius p1 about its anchor (the
    struts stay parallel). Usually none."""
    scale = max(L2, L3, abs(x1), math.hypot(x2, y2), p1, p2, p3)
    theta = 0.0 if x1 > 0 else math.pi  # the turn that puts the second vertex's offset on (x1, 0)
    if abs(L3 - abs(x1)) > 1e-9 * scale or max(abs(p2 - p1), abs(p3 - p1)) > 1e-9 * scale:
        return []
    offsets = _offsets(np.array(theta), L2, L3, gamma, x1, x2, y2, p1, p2, p3)[:4]
    return [theta] if max(abs(float(x)) for x in offsets) <= 1e-9 * scale else []


def sweep_strut(params: dict[str, float], strut: str, values: np.ndarray,
                progress: bool = False) -> tuple[np.ndarray, list[tuple[float, int, int]]]:  # fmt: skip
    """Number of poses as strut ``strut`` ("p1", "p2" or "p3") takes each of ``values``.

    Returns (counts, changes): ``changes`` lists (length, count before, count
    after) at each length where the count changes, located by bisection between
    grid values to 1e-6 of the sweep's span.
    """
    if strut not in ("p1", "p2", "p3"):
        raise ConfigError(f"strut must be p1, p2 or p3, got {strut!r}")
    values = finite_array("values", values, (None,))
    if not np.all(np.diff(values) > 0):
        raise ConfigError("values must rise from the shortest length to the longest (the bisection relies on it)")

    def count(v: float) -> int:
        return len(solve_planar(**{**params, strut: float(v)}))

    bar = Progress(len(values), "lengths", f"sweeping {strut}") if progress else None  # (a bar on a terminal)
    counts = np.zeros(len(values), dtype=int)
    for k, v in enumerate(values):
        counts[k] = count(v)
        if bar is not None:
            bar.advance()
    if bar is not None:
        bar.close()
    changes = []
    span = float(values[-1] - values[0]) if len(values) > 1 else 1.0
    for i in np.flatnonzero(np.diff(counts) != 0):
        lo, hi = values[i], values[i + 1]
        c_lo = counts[i]
        while hi - lo > 1e-6 * abs(span):
            mid = (lo + hi) / 2
            if count(mid) == c_lo:
                lo = mid
            else:
                hi = mid
        changes.append((float((lo + hi) / 2), int(counts[i]), int(counts[i + 1])))
    return counts, changes
