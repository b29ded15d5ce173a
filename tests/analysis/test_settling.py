"""The lower bound on settling under the LQR's model (``stewart_gym.analysis.settling``)."""


import math

from stewart_gym.control import LQRDesign


def test_fastest_settling_matches_bang_bang_on_an_ideal_actuator_and_orders_as_it_should() -> None:
    """With a near-instant tilt (0.1 ms lag, 5 ms periods) the bound is the bang-bang time of an independent
    derivation: from rest at 100 mm, full tilt towards the target, then full tilt back so that the ball enters
    the 10 mm circle just fast enough to stop at its far edge (a 16-gon inside it), plus the one period of dead
    time. A larger tilt is faster, a farther start slower, and the diagonal (both axes at full tilt) faster."""
    from stewart_gym.analysis.settling import fastest_settling

    accel = 5 / 7 * 9.80665 * math.sin(math.radians(10))
    inner = 0.010 * math.cos(math.pi / 16)  # the polygon's inscribed radius
    s1 = (0.1 - inner + 2 * inner) / 2  # accelerate over s1, brake over s2: s1 + s2 = 0.1 − r, s1 − s2 = 2r
    t1 = math.sqrt(2 * s1 / accel)
    t2 = (accel * t1 - math.sqrt(2 * accel * 2 * inner)) / accel
    ideal = LQRDesign(tilt_lag_s=1e-4)
    bound = fastest_settling((0.1, 0.0), 0.010, design=ideal, dt=0.005)
    assert t1 + t2 + 0.005 - 1e-9 <= bound <= t1 + t2 + 0.005 + 0.0075, (bound, t1 + t2 + 0.005)
    reference = fastest_settling((0.1, 0.0), 0.010)
    assert fastest_settling((0.1, 0.0), 0.010, max_tilt=math.radians(15)) < reference
    assert fastest_settling((0.12, 0.0), 0.010) > reference > fastest_settling((0.1 / math.sqrt(2),) * 2, 0.010)
