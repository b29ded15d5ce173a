"""Progress of long runs: a line at least every 10 s where the output is not a terminal (a pipe, a log file), with
what is done of the total and the time left; and the commands that run long print it before their result."""

from __future__ import annotations

import io
import os
import subprocess
import sys

import pytest

from stewart_gym.progress import Progress, duration


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_lines_come_every_interval_with_done_total_and_time_left() -> None:
    clock, out = Clock(), io.StringIO()
    progress = Progress(200, "episodes", "evaluate", stream=out, interval_s=10.0, clock=clock)
    for _ in range(39):  # 19.5 episodes in 9.75 s: no line yet
        clock.now += 0.25
        progress.advance(0.5)
    assert out.getvalue() == ""
    clock.now += 0.25
    progress.advance(0.5)  # 20 episodes in 10 s
    assert out.getvalue() == "evaluate: 20/200 episodes (10 %), 0:10 elapsed, about 1:30 left\n"
    clock.now += 5.0
    progress.advance(10)
    assert out.getvalue().count("\n") == 1  # not before another 10 s
    clock.now += 5.0
    progress.advance(0.5)
    # the pace since the first half episode (at 0.25 s): 30 episodes in 19.75 s, 169.5 to go
    assert out.getvalue().splitlines()[-1] == "evaluate: 30/200 episodes (15 %), 0:20 elapsed, about 1:52 left"
    progress.stopped("--max-minutes 1 reached")
    assert out.getvalue().splitlines()[-1] == "evaluate: stopped at 30/200 episodes: --max-minutes 1 reached"


def test_the_time_left_leaves_the_start_up_out() -> None:
    """A run whose first step comes after 15 s of start-up (building the envs and the model, compiling the
    batched kernel), then 1,000 steps a second: the time left is at that pace (0:20 for 20,000 steps), not at the
    pace from the start (which would say over an hour); and no line comes before the second step."""
    clock, out = Clock(), io.StringIO()
    progress = Progress(30_000, "steps", "train", stream=out, interval_s=10.0, clock=clock)
    clock.now += 15.0
    progress.advance(128)
    assert out.getvalue() == ""  # 15 s have passed, but one step gives no pace
    clock.now += 0.128
    progress.advance(128)
    assert out.getvalue() == "train: 256/30,000 steps (1 %), 0:15 elapsed, about 0:30 left\n"
    for _ in range(79):  # 10,112 steps more in 10.112 s
        clock.now += 0.128
        progress.advance(128)
    assert out.getvalue().splitlines()[1:] == ["train: 10,368/30,000 steps (35 %), 0:25 elapsed, about 0:20 left"]


@pytest.mark.parametrize("value", ["0", "-5", "nan", "inf", "ten", "1e9"])
def test_a_bad_progress_interval_is_one_error_line_before_any_work(value: str, monkeypatch: pytest.MonkeyPatch,
                                                                    capfd: pytest.CaptureFixture[str],
                                                                    tmp_path) -> None:  # fmt: skip
    from stewart_gym.cli import main

    monkeypatch.setenv("STEWART_GYM_PROGRESS_S", value)
    plot = tmp_path / "plot.png"
    assert main(["evaluate", "--policy", "pid", "--episodes", "1", "--json", "--plot", str(plot)]) == 1
    out, err = capfd.readouterr()
    assert err.startswith("error: STEWART_GYM_PROGRESS_S must be") and repr(value) in err and err.count("\n") == 1
    assert out == "" and not plot.exists()  # no episode ran


def test_the_progress_interval_comes_from_the_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    from stewart_gym.progress import LINE_INTERVAL_S, line_interval_s

    monkeypatch.delenv("STEWART_GYM_PROGRESS_S", raising=False)  # unset, even where the user's shell sets it
    assert line_interval_s() == LINE_INTERVAL_S
    monkeypatch.setenv("STEWART_GYM_PROGRESS_S", " 60 ")
    assert line_interval_s() == 60.0 and Progress(5, "steps", "train").interval_s == 60.0
    assert Progress(5, "steps", "train", interval_s=2.0).interval_s == 2.0


def test_durations_read_as_clock_times() -> None:
    assert [duration(s) for s in (0, 9.6, 61, 3599, 3723)] == ["0:00", "0:10", "1:01", "59:59", "1:02:03"]
    with pytest.raises(ValueError, match="positive"):
        Progress(0, "steps", "train")


def test_a_piped_evaluate_prints_progress_before_its_result_as_often_as_the_variable_says() -> None:
    """A piped ``evaluate`` prints progress lines before its result, one every ``$STEWART_GYM_PROGRESS_S``
    seconds (here 0.1 s, so that 20 episodes of a few seconds print several)."""
    proc = subprocess.run([sys.executable, "-m", "stewart_gym", "evaluate", "--policy", "pid", "--episodes", "20"],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=900,
                          env={**os.environ, "STEWART_GYM_PROGRESS_S": "0.1"})  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:]
    lines = proc.stdout.splitlines()
    progress = [i for i, line in enumerate(lines) if line.startswith("evaluate: ") and "/20 episodes (" in line]
    result = next(i for i, line in enumerate(lines) if line.startswith("success rate"))
    assert len(progress) >= 2 and max(progress) < result, lines[:10]  # at the default 10 s: none
    assert all("elapsed, about " in lines[i] and lines[i].endswith(" left") for i in progress)


def test_train_stopped_by_max_minutes_says_so(tmp_path, capfd: pytest.CaptureFixture) -> None:
    """``train --max-minutes``: the run ends early, keeps its model, and one ``note:`` line says it stopped and at
    how many of the planned steps; metrics.json records why."""
    import json

    from stewart_gym.cli import main

    hp = tmp_path / "hp.yml"
    hp.write_text("StewartBallBalance-v0:\n  n_envs: 1\n  n_timesteps: 1000000\n  policy: MlpPolicy\n"
                  "  n_steps: 64\n  batch_size: 64\n  n_epochs: 1\n  policy_kwargs: {net_arch: [8]}\n")  # fmt: skip
    run = tmp_path / "run"
    code = main(["train", "--hyperparams", str(hp), "--run-dir", str(run), "--max-minutes", "0.05",
                 "--eval-freq", "100000", "--no-tensorboard"])  # fmt: skip
    err = capfd.readouterr().err
    metrics = json.loads((run / "metrics.json").read_text())
    assert code == 0 and metrics["stopped"] == "max_wall_s" and 0 < metrics["timesteps"] < 1_000_000
    assert f"note: stopped by --max-minutes 0.05: {metrics['timesteps']:,} steps trained (1,000,000 planned)" in err
    assert (run / "model.zip").exists()
