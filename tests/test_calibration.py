"""Servo calibration: eqs 13/14, limits, TOML."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from stewart_gym.calibration import CalibrationError, PulseRangeError, ServoCalibration
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.presets import load_preset


@pytest.fixture
def cal() -> ServoCalibration:
    return ServoCalibration.default("servo-hexapod")


def test_default_is_seed_000(cal: ServoCalibration) -> None:
    g = load_preset("servo-hexapod")
    home = inverse_kinematics(g, np.zeros(6)).servo_angles
    assert cal.pulse_widths(home) == pytest.approx(np.full(6, 1500.0))
    assert cal.direction.tolist() == [1, -1, 1, -1, 1, -1]
    assert cal.us_per_rad == pytest.approx(np.full(6, 1600 / math.pi))
    # 45° of travel is 400 µs, even servos up, odd servos down (mirrored mounting)
    w = cal.pulse_widths(home + math.radians(45))
    assert w == pytest.approx([1900, 1100, 1900, 1100, 1900, 1100])
    # the limits bound the geometry's ±45° travel exactly
    assert cal.min_us == pytest.approx(np.full(6, 1100.0)) and cal.max_us == pytest.approx(np.full(6, 1900.0))


def test_eq13_eq14_with_trims() -> None:
    cal = ServoCalibration.default("servo-hexapod", trims_us=np.array([10, -20, 0, 5, 0, -5]))
    angles = cal.home_angle + np.array([0.1, 0.1, -0.2, -0.2, 0.0, 0.05])
    r = 1600 / math.pi
    expected = [1510 + 0.1 * r, 1480 - 0.1 * r, 1500 - 0.2 * r, 1505 + 0.2 * r, 1500, 1495 - 0.05 * r]
    assert cal.pulse_widths(angles) == pytest.approx(expected)
    assert cal.angles(cal.pulse_widths(angles)) == pytest.approx(angles)


def test_out_of_range_is_an_error_unless_asked(cal: ServoCalibration) -> None:
    angles = np.tile(cal.home_angle, (3, 1))
    angles[1, 3] += math.radians(50)  # servo 3 is mirrored: 1500 − 444 µs
    with pytest.raises(PulseRangeError, match="servo 3"):
        cal.pulse_widths(angles)
    clipped = cal.pulse_widths(angles, out_of_range="clip")
    assert clipped[1, 3] == pytest.approx(1100.0) and clipped[0] == pytest.approx(np.full(6, 1500.0))
    nan = cal.pulse_widths(angles, out_of_range="nan")
    assert np.isnan(nan[1, 3]) and np.isfinite(np.delete(nan.ravel(), 9)).all()
    angles[2, 0] = np.nan
    with pytest.raises(PulseRangeError):
        cal.pulse_widths(angles, out_of_range="clip")  # NaN is never clipped into range
    with pytest.raises(PulseRangeError):
        cal.check(np.array([1500, 1500, 1500, 1500, 1500, 2500.0]))
    assert cal.in_range(np.array([1100, 1900, 1500, 1099.9, 1900.1, np.inf])).tolist() == [
        True, True, True, False, False, False]  # fmt: skip


CAL_TOML = """
geometry = "servo-hexapod"
us_per_degree = 10.0
[[servo]]
channel = 6
trim_us = 12
[[servo]]
channel = 7
direction = 1
[[servo]]
channel = 8
min_us = 1000
max_us = 2000
[[servo]]
channel = 9
[[servo]]
channel = 10
[[servo]]
channel = 11
trim_us = -8
"""


def test_calibration_toml(tmp_path: Path) -> None:
    path = tmp_path / "cal.toml"
    path.write_text(CAL_TOML)
    cal = ServoCalibration.from_toml(path)
    assert cal.channels == (6, 7, 8, 9, 10, 11)
    assert cal.neutral_us.tolist() == [1512, 1500, 1500, 1500, 1500, 1492]
    assert cal.direction.tolist() == [1, 1, 1, -1, 1, -1]
    assert cal.us_per_rad == pytest.approx(np.full(6, 10 * 180 / math.pi))
    assert (cal.min_us[2], cal.max_us[2]) == (1000, 2000)
    # default limits follow the geometry's ±45° around the trimmed neutral
    assert (cal.min_us[0], cal.max_us[0]) == pytest.approx((1512 - 450, 1512 + 450))
    # round trip
    again = tmp_path / "again.toml"
    again.write_text(cal.to_toml())
    assert ServoCalibration.from_toml(again) == cal


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (("channel = 6\ntrim_us = 12", "channel = 6\ntrim_us = \"x\""), r"servo\[0\].trim_us"),
        (("channel = 7\ndirection = 1", "channel = 7\ndirection = 2"), "direction"),
        (("min_us = 1000", "min_us = 2100"), "min_us"),
        (("channel = 9", "channel = 8"), "channels"),
        (("channel = 10", "channel = 10\nspeed = 3"), r"servo\[4\]"),
        (("us_per_degree = 10.0", "us_per_degree = 10.0\nport = 3"), "port"),
        (("[[servo]]\nchannel = 11\ntrim_us = -8", ""), "servo"),
        (("geometry = \"servo-hexapod\"", ""), "geometry"),
        (("channel = 6\ntrim_us = 12", "channel = 6\ntrim_us = 5000"), r"^servo\[0\].trim_us: .*got 1500 \+ 5000"),
        (("channel = 11\ntrim_us = -8", "channel = 11\ntrim_us = -1200"), r"^servo\[5\].trim_us"),
        (("us_per_degree = 10.0", "us_per_degree = 10.0\nneutral_us = -1500"), r"^neutral_us: .*got -1500"),
        (("us_per_degree = 10.0", "us_per_degree = 10.0\nneutral_us = 1e9"), r"^neutral_us"),
        (("us_per_degree = 10.0", "us_per_rad = 1e12"), r"^us_per_rad: the servos' gain, 50–5000 µs/rad .*got 1000000000000"),  # noqa: E501
        (("us_per_degree = 10.0", "us_per_degree = 0.01"), r"^us_per_degree: the servos' gain, 0\.87.*µs/°"),
    ],
)
def test_bad_calibration_names_the_field(tmp_path: Path, edit: tuple[str, str], field: str) -> None:
    old, new = edit
    assert old in CAL_TOML
    path = tmp_path / "cal.toml"
    path.write_text(CAL_TOML.replace(old, new, 1))
    with pytest.raises(CalibrationError, match=field):
        ServoCalibration.from_toml(path)


def test_a_home_angle_given_on_some_servos_is_theirs_and_the_geometrys_on_the_rest(tmp_path: Path) -> None:
    """home_angle_deg on servo 0 alone: servo 0's home angle is the one given (its pulse at the geometry's home
    moves by its gain times the difference), the other five keep the geometry's; without a geometry, the servos
    that give none are named."""
    base = ServoCalibration.from_toml(_written(tmp_path / "a.toml", CAL_TOML))
    edited = ServoCalibration.from_toml(_written(tmp_path / "b.toml", CAL_TOML.replace(
        "channel = 6\ntrim_us = 12", "channel = 6\ntrim_us = 12\nhome_angle_deg = 20")))  # fmt: skip
    assert edited.home_angle[0] == pytest.approx(math.radians(20.0))
    assert np.array_equal(edited.home_angle[1:], base.home_angle[1:])
    home = base.home_angle.copy()
    shift = edited.pulse_widths(home)[0] - base.pulse_widths(home)[0]
    assert shift == pytest.approx(base.us_per_rad[0] * (base.home_angle[0] - math.radians(20.0)))
    ends = np.array(load_preset("servo-hexapod").servo_angle_range)  # its limits: the pulses at the travel's ends
    at_ends = edited.neutral_us[0] + edited.direction[0] * (ends - edited.home_angle[0]) * edited.us_per_rad[0]
    assert (edited.min_us[0], edited.max_us[0]) == pytest.approx((min(at_ends), max(at_ends)), abs=1e-5)
    lone = CAL_TOML.replace('geometry = "servo-hexapod"\n', "").replace("trim_us = 12", "trim_us = 12\nhome_angle_deg = 20")
    with pytest.raises(CalibrationError, match=r"^geometry: needed for the home angles of servo\[1\], servo\[2\]"):
        ServoCalibration.from_dict(__import__("tomllib").loads(lone))


def _written(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_linear_actuators_map_the_stroke_onto_1000_to_2000_us() -> None:
    """RC linear actuators: fully retracted at 1000 µs, extended at 2000 µs, linear in leg length between."""
    from stewart_gym.kinematics import inverse_kinematics

    geo = load_preset("senilov2018")
    cal = ServoCalibration.default(geo)
    assert cal.actuator == "linear"
    lo, hi = geo.leg_length_range
    assert np.allclose(cal.pulse_widths(np.full(6, lo)), 1000.0) and np.allclose(cal.pulse_widths(np.full(6, hi)), 2000.0)
    home = inverse_kinematics(geo, np.zeros(6)).leg_lengths
    assert np.allclose(cal.neutral_us, 1000.0 + 1000.0 * (home - lo) / (hi - lo))
    mid = np.full(6, (lo + hi) / 2)
    assert np.allclose(cal.angles(cal.pulse_widths(mid)), mid)


@pytest.mark.parametrize(("change", "named"), [
    ({"max_us": 1e9}, "max_us"),  # a pulse no servo takes
    ({"min_us": 100.0}, "min_us"),
    ({"channels": "012345"}, "channels"),  # a string's characters
    ({"channels": (0.5, 1, 2, 3, 4, 5)}, "channels"),  # 0.5 was channel 0
    ({"channels": (True, 1, 2, 3, 4, 5)}, "channels"),
])  # fmt: skip
def test_the_constructor_refuses_what_a_calibration_file_may_not_hold(change: dict, named: str) -> None:
    base = ServoCalibration.default(load_preset("servo-hexapod"))
    fields = {k: getattr(base, k) for k in ("neutral_us", "direction", "home_angle", "us_per_rad", "min_us", "max_us",
                                            "channels")}  # fmt: skip
    with pytest.raises(CalibrationError, match=named):
        ServoCalibration(**{**fields, **change})


def test_the_methods_refuse_a_wrong_count_of_pulses_and_an_unknown_mode() -> None:
    cal = ServoCalibration.default(load_preset("servo-hexapod"))
    with pytest.raises(ValueError, match="out_of_range"):
        cal.pulse_widths(np.zeros(6), out_of_range="bogus")  # (taken while every pulse was in range)
    with pytest.raises(ValueError, match="pulse_widths"):
        cal.in_range(np.full(5, 1500.0))
    with pytest.raises(ValueError, match="pulse_widths"):
        cal.check(np.full(5, 1500.0))
    with pytest.raises(ValueError, match="6 pulses"):
        cal.in_range_one([1500.0] * 5)  # (True: five pulses checked)
    with pytest.raises(ValueError, match="6 pulses"):
        cal.angles_one([1500.0] * 7)
    assert cal.in_range_one([1500.0] * 6) and cal.in_range(np.full(6, 1500.0)).all()


def test_a_geometry_hash_that_is_not_hex_is_refused(tmp_path: Path) -> None:
    from stewart_gym.hardware.deploy_setup import load_calibration

    path = tmp_path / "cal.toml"
    path.write_text('geometry = "servo-hexapod"\ngeometry_sha256 = "' + "z" * 64 + '"\n')
    with pytest.raises(CalibrationError, match="geometry_sha256 must be the 64 hex digits"):
        load_calibration(str(path), "servo-hexapod")
