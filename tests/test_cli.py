"""The stewart-gym command line."""

from __future__ import annotations

import json

import pytest

from stewart_gym.cli import main


def test_ik_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["ik", "0", "0", "5", "3", "0", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["reachable"] is True and len(out["pulse_widths_us"]) == 6
    assert main(["ik", "0", "0", "30", "0", "0", "0", "--json"]) == 1  # unreachable: non-zero exit
    out = json.loads(capsys.readouterr().out)
    assert out["reachable"] is False and out["servo_angles_deg"] == [None] * 6


def test_ik_linear_geometry(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["ik", "--geometry", "senilov2018", "200", "0", "0", "0", "0", "0"]) == 1
    assert "above the upper actuator limit" in capsys.readouterr().out
