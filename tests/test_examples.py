"""Each script of ``examples/`` runs as its docstring says, briefly (TorchRL's and RLlib's: tests/test_rl_libraries.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import load_example

from stewart_gym.presets import load_geometry


def test_classical_controller_holds_the_ball(capsys: pytest.CaptureFixture) -> None:
    load_example("classical_controller").main(["--controller", "lqr-pid", "--episodes", "2"])
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("episode 0: held, ") and out[-1] == "success 2/2"


def test_own_platform_writes_a_symmetric_geometry_and_balances_on_it(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    path = tmp_path / "mine.toml"
    load_example("own_platform").main(["--base-radius", "105", "--rod", "165", "--episodes", "2", "--out", str(path)])
    out = capsys.readouterr().out.splitlines()
    geometry = load_geometry(path)
    assert "[symmetric]" in path.read_text() and geometry.name == "my-platform"
    assert abs(float(geometry.base_anchors[0, 0]) ** 2 + float(geometry.base_anchors[0, 1]) ** 2 - 0.105**2) < 1e-12
    assert out[0] == f"{path}: home height {1e3 * geometry.home_height:.2f} mm"
    assert out[1].startswith("home: servo angles ") and "1500, 1500, 1500, 1500, 1500, 1500" in out[1]
    assert out[-1] == "PID + Kalman on my-platform: success 2/2"


def test_deploy_virtual_board_homes_and_the_board_confirms(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code = load_example("deploy_virtual_board").main(["--duration", "2", "--log", str(tmp_path / "log.csv")])
    out = capsys.readouterr().out
    assert code == 0 and "servos homed: confirmed by the board" in out and "virtual board: virtual line: " in out
    assert len((tmp_path / "log.csv").read_text().splitlines()) > 50


@pytest.mark.slow
def test_train_sb3_trains_and_evaluates(capsys: pytest.CaptureFixture) -> None:
    load_example("train_sb3").main(["--timesteps", "2048", "--episodes", "1"])
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("episode 0: ") and out[-1] in ("success 0/1", "success 1/1")


def test_the_examples_refuse_bad_input_in_one_line_and_keep_files(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    """A usage mistake is one ``error:`` line and exit 1, as in the command line; ``own_platform`` replaces a file
    only with --overwrite and writes none that describes no platform; ``deploy_virtual_board`` checks its log
    before it starts the board."""
    (tmp_path / "mine.toml").write_text("my notes\n")
    cases = [("classical_controller", ["--episodes", "0"], "--episodes: '0' must be at least 1"),
             ("own_platform", ["--out", str(tmp_path / "mine.toml")], "mine.toml exists; give another name or --overwrite"),
             ("own_platform", ["--rod", "10", "--out", str(tmp_path / "bad.toml")],
              f"{tmp_path / 'bad.toml'}: the chains cannot close at home, "),  # its rods, not a home_height it
             # was never given, come first:
             ("own_platform", ["--rod", "20", "--out", str(tmp_path / "bad.toml")], "check rod_length, horn_length"),
             ("own_platform", ["--rod", "1e308", "--out", str(tmp_path / "huge.toml")], "larger than any build"),
             ("deploy_virtual_board", ["--duration", "-1"], "--duration: '-1' must be greater than 0"),
             ("deploy_virtual_board", ["--log", str(tmp_path / "mine.toml")], "expected a file name ending in .csv")]
    for script, args, says in cases:
        with pytest.raises(SystemExit) as stop:
            code = load_example(script).main(args)
            raise SystemExit(code)
        err = capsys.readouterr().err
        lines = [line for line in err.splitlines() if line.strip()]
        message = stop.value.code if isinstance(stop.value.code, str) else (lines[0] if lines else "")
        assert stop.value.code not in (0, None, 2) and says in str(message), (script, args, err, stop.value.code)
        assert len(lines) <= 1 and "Traceback" not in err
    assert (tmp_path / "mine.toml").read_text() == "my notes\n"
    assert not (tmp_path / "bad.toml").exists() and not (tmp_path / "huge.toml").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.toml"]  # no scratch folder left either
