"""The ball-sensor seam: checks every sensor must pass, simulated (env) and real (deploy) alike."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from conftest import FakeDevice

from stewart_gym.sensing import BallSensor, SimulatedSensor, SimulatedTouchPanel, TouchPanelSpec, ball_contact


def _panel() -> SimulatedTouchPanel:
    return SimulatedTouchPanel(TouchPanelSpec(noise_mm=1.0, rate_hz=100.0, latency_s=0.01))


def _camera() -> SimulatedSensor:
    from dataclasses import replace

    from stewart_gym.camera import CAMERA_PRESETS, SimulatedCamera

    return SimulatedCamera(replace(CAMERA_PRESETS["webcam30"], miss_rate=0.0, centroid_noise_px=1.0))


def _panel_row() -> SimulatedSensor:
    from stewart_gym.sensing_arrays import PanelArray, PanelRow

    panels = PanelArray(3, 0.02)
    panels.set_spec(1, TouchPanelSpec(noise_mm=1.0, rate_hz=100.0, latency_s=0.01))
    return PanelRow(panels, 1)


def _camera_row() -> SimulatedSensor:
    from stewart_gym.sensing_arrays import CameraArray, CameraRow

    return CameraRow(CameraArray(3, 0.02, _camera().spec), 2)


#: The simulated sensors, each made with about 1 mm of noise per axis (the contract checks that noise) and
#: sampling at 30 Hz or faster.
SIMULATED = {"touch-panel": _panel, "camera": _camera, "panel-row": _panel_row, "camera-row": _camera_row}


def _readings(sensor: SimulatedSensor, seed: int) -> list:
    """What ``sensor`` reads over 2 s of a ball moving along x, reset with a generator seeded ``seed``."""
    sensor.reset(0.0, (0.02, -0.01), np.random.default_rng(seed))
    out = []
    for k in range(1, 101):
        t = k * 0.02
        sensor.record(t, (0.02 + 0.05 * math.sin(t), -0.01), True)
        out.append(sensor.read(t))
    return out


@pytest.mark.parametrize("name", sorted(SIMULATED))
def test_simulated_sensor_contract(name: str) -> None:
    """A simulated sensor reports recorded positions, never from the future, with its noise, nothing when off."""
    sensor = SIMULATED[name]()
    assert isinstance(sensor, SimulatedSensor) and isinstance(sensor, BallSensor)
    rng = np.random.default_rng(0)
    sensor.reset(0.0, (0.02, -0.01), rng)
    errors = []
    for k in range(1, 201):
        t = k * 0.02
        truth = (0.02 + 0.05 * math.sin(t), -0.01)
        sensor.record(t, truth, True)
        got = sensor.read(t)
        assert got is not None
        (x, y), t_sample = got
        assert t_sample <= t and math.isfinite(x + y)
        errors.append(math.hypot(x - (0.02 + 0.05 * math.sin(t_sample)), y + 0.01))
    assert 0.0003 < float(np.sqrt(np.mean(np.square(errors)))) < 0.003  # about its 1 mm noise per axis
    for k in range(201, 260):  # the ball leaves: the last touching sample ages, nothing newer arrives
        sensor.record(k * 0.02, (0.3, 0.0), False)
    got = sensor.read(259 * 0.02)
    assert got is None or 259 * 0.02 - got[1] > 0.5


@pytest.mark.parametrize("name", sorted(SIMULATED))
def test_a_simulated_sensor_draws_its_noise_from_the_reset_s_generator(name: str) -> None:
    """The same seed gives the same readings, to the last bit (so that a seeded episode repeats); another seed
    other noise."""
    first, again, other = (_readings(SIMULATED[name](), seed) for seed in (5, 5, 6))
    assert first == again
    assert first != other


def test_the_real_panel_is_a_ball_sensor(device: FakeDevice) -> None:
    """deploy's PanelSensor reads the line protocol's B x,y (mm) as metres with the sample's time on its clock."""
    import threading

    from stewart_gym.hardware.deploy import PanelSensor
    from stewart_gym.hardware.serial_controllers import LineController

    threading.Timer(0.2, lambda: device.write(b"ready\n")).start()
    controller = LineController(device.path, ready_timeout=3.0)
    sensor = PanelSensor(controller)
    assert isinstance(sensor, BallSensor)
    assert sensor.read(10.0) is None  # nothing received yet
    device.write(b"B 12.5,-7.0\n")
    time.sleep(0.05)
    (x, y), t_sample = sensor.read(10.0)
    assert (x, y) == pytest.approx((0.0125, -0.007)) and 9.5 < t_sample <= 10.0
    controller.close()


def test_ball_contact_rule() -> None:
    half, top, r = (0.15, 0.10), 0.012, 0.0127
    assert ball_contact(0.0, 0.0, top + r, half, top, r) == (True, True)
    assert ball_contact(0.0, 0.12, top + r, half, top, r) == (False, False)  # beyond the short side
    assert ball_contact(0.0, 0.0, top + 2 * r, half, top, r) == (True, False)  # in the air
    assert ball_contact(0.0, 0.0, top - 0.001, half, top, r) == (False, False)  # below the surface
    # the same balls as arrays, one per row, and a NaN: each row as alone
    x, y = np.array([0.0, 0.0, 0.0, 0.0, np.nan]), np.array([0.0, 0.12, 0.0, 0.0, 0.0])
    z = np.array([top + r, top + r, top + 2 * r, top - 0.001, top + r])
    on, touching = ball_contact(x, y, z, half, top, np.full(5, r))
    assert on.tolist() == [True, False, True, False, False] and touching.tolist() == [True, False, False, False, False]
