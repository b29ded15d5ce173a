"""Finding servo trims by hand: the procedure behind ``stewart-gym calibrate``.

One servo at a time is nudged until its horn is level, or its leg at the home length (the neutral pose),
with keys read line by line: ``+`` / ``-`` move the selected servo by the step,
``n`` selects the next servo, ``q`` saves and quits (so does the end of the
input). The pulses sent always stay within the channel limits. At the end the
servos are left at the *new* neutral, and the calibration is written as TOML
with its ``[hardware]`` table (port, protocol, baud rate) so that ``deploy
--calibration FILE`` needs no more options.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.calibration import PULSE_LIMITS_US, ServoCalibration
from stewart_gym.hardware.serial_controllers import ServoController

__all__ = ["TrimResult", "calibration_toml", "find_trims"]

#: Pulse values in the written file are rounded to this many decimals (µs): no float noise such as 1084.999999.
DECIMALS = 3
KEYS_HELP = "+ / - move the servo, n = next servo, q = save and quit"


@dataclass
class TrimResult:
    calibration: ServoCalibration
    presses: int
    unknown_keys: int


def find_trims(controller: ServoController, start: ServoCalibration, keys: Iterable[str], step_us: float,
               say: Callable[[str], None] = print, nominal_us: np.ndarray | float = 1500.0) -> TrimResult:  # fmt: skip
    """Run the procedure on ``controller``; returns the new calibration (the channel limits move with the trim).

    Trims are shown against ``nominal_us``, the untrimmed neutral pulses (1500 µs for hobby servos; the pulse of
    the home leg length for RC linear actuators).
    """
    nominal = np.broadcast_to(np.asarray(nominal_us, dtype=float), (6,))
    trims = np.round(start.neutral_us - nominal, DECIMALS)
    servo, presses, unknown = 0, 0, 0

    def pulses() -> np.ndarray:
        return np.clip(nominal + trims, start.min_us, start.max_us)

    finished = False
    try:
        say(f"servo 0: {KEYS_HELP} ({step_us:g} µs per press)")
        controller.send(pulses())
        for line in keys:
            key = line.strip()
            if key in ("+", "-"):
                # the trim may not take the neutral pulse past the channel limits
                trims[servo] = float(np.clip(round(trims[servo] + (step_us if key == "+" else -step_us), DECIMALS),
                                             start.min_us[servo] - nominal[servo],
                                             start.max_us[servo] - nominal[servo]))  # fmt: skip
                presses += 1
            elif key == "n":
                servo = (servo + 1) % 6
            elif key == "q":
                break
            elif key:
                unknown += 1
                say(f"unknown key {key!r}: {KEYS_HELP}")
                continue
            controller.send(pulses())
            say(f"servo {servo}: trims {np.round(trims, 1).tolist()} µs")
        finished = True
    finally:
        # the channel limits move with the neutral pulse, within any servo's (so that the file reads back)
        shift = nominal + trims - start.neutral_us
        lowest, highest = PULSE_LIMITS_US
        cal = ServoCalibration(nominal + trims, start.direction, start.home_angle, start.us_per_rad,
                               np.round(np.maximum(start.min_us + shift, lowest), DECIMALS),
                               np.round(np.minimum(start.max_us + shift, highest), DECIMALS),
                               start.channels, start.actuator)  # fmt: skip
        if finished:
            controller.send(np.clip(cal.neutral_us, cal.min_us, cal.max_us))  # rest at the new neutral
    return TrimResult(cal, presses, unknown)


def calibration_toml(cal: ServoCalibration, hardware: dict[str, Any], geometry: str | None = None,
                     folder: str | Path = ".") -> str:  # fmt: skip
    """The calibration file, to be written into ``folder``: the geometry it is for, the calibration and a
    ``[hardware]`` table with the entries that are set. A geometry file is named by its path from ``folder``
    (so that the pair can move together) with ``geometry_sha256``, its content's hash (so that the file can move
    alone, and a changed one is noticed)."""
    from stewart_gym.presets import PRESETS, load_geometry

    head = ""
    if geometry and geometry not in PRESETS:
        try:
            where = Path(os.path.relpath(Path(geometry).resolve(), Path(folder).resolve())).as_posix()  # (any OS)
        except ValueError:  # on another drive than the folder (Windows): named whole
            where = Path(geometry).resolve().as_posix()
        head = f"geometry = {json.dumps(where)}\ngeometry_sha256 = \"{load_geometry(geometry).content_hash()}\"\n"
    elif geometry:
        head = f"geometry = {json.dumps(str(geometry))}\n"
    text = head + cal.to_toml(geometry)
    table = {k: v for k, v in hardware.items() if v is not None}
    if table:
        text += "\n[hardware]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in sorted(table.items()))
    return text
