"""The ``stewart-gym`` command line, run as a user runs it: in a subprocess, checking exit codes and output.

Two tables:

* ``GOOD``: every subcommand's ``--help`` and every documented example, with its exit code and output;
* ``BAD``: a user mistake of each kind for each subcommand. Each must exit non-zero (1, or 2 for a
  device failure) with exactly one ``error: …`` line and no traceback, before any long work starts.

Then end-to-end runs through the real command line with a fake serial device (a pty): the deploy dry run,
an unplug, a track bundle, calibrate with scripted keys, and a policy trained in ``pose`` and ``pulse`` mode
through train → evaluate → export → deploy.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import Board, Drain, FakeDevice, cli, maestro_frames, sg, sg_in

ROOT = Path(__file__).resolve().parents[2]
SUBCOMMANDS = ("ik", "urdf", "mjcf", "render", "train", "evaluate", "export", "deploy", "calibrate", "workspace",
               "trajectory", "sensitivity", "conditioning", "planar", "assembly", "demo", "virtual-device",
               "camera-check", "sweep", "ensemble", "compare")  # fmt: skip


def error_lines(proc: subprocess.CompletedProcess) -> list[str]:
    """The stderr lines a user would read: all of them (the simulator keeps PyBullet's import banner off it)."""
    return [ln for ln in proc.stderr.splitlines() if ln.strip()]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Malformed and well-formed inputs of every kind the commands read."""
    from stewart_gym.presets import load_preset

    d = tmp_path_factory.mktemp("inputs")
    (d / "binary.toml").write_bytes(bytes(range(256)) * 4)
    (d / "binary.csv").write_bytes(b"\xff\xfe\x00\x81" * 64)
    (d / "bad.toml").write_text("this is = = not toml\n")
    (d / "partial.toml").write_text('kind = "rotary"\nlength_unit = "mm"\n')
    (d / "planar_partial.toml").write_text("L1 = 2.0\n")
    (d / "bad.yml").write_text("ppo: [unclosed\n")
    (d / "other.yml").write_text("SomethingElse-v0:\n  n_envs: 1\n")
    (d / "bad_reward.yml").write_text("StewartBallBalance-v0:\n  n_envs: 2\n  env_kwargs: {outside_penalty: -1}\n")
    (d / "env_kwargs_unknown.yml").write_text("StewartBallBalance-v0:\n  n_envs: 2\n"
                                              "  env_kwargs: {backend: batched, bogus: 1}\n")
    (d / "env_kwargs_list.yml").write_text("StewartBallBalance-v0:\n  n_envs: 2\n  env_kwargs: [backend, batched]\n")
    (d / "ppo_noise.yml").write_text("StewartBallBalance-v0:\n  n_envs: 1\n  noise_type: normal\n  noise_std: 0.1\n")
    (d / "bad_noise.yml").write_text("StewartBallBalance-v0:\n  n_envs: 1\n  noise_type: pink\n  noise_std: 0.1\n")
    (d / "ppo_keys.yml").write_text("StewartBallBalance-v0:\n  n_envs: 1\n  n_epochs: 5\n")
    (d / "dwell_no_latch.yml").write_text("StewartBallTrack-v0:\n  n_envs: 1\n"
                                          "  residual: {base: lqr, inner_mm: 2, fade_mm: 15, dwell_s: 3}\n")
    (d / "notes.txt").write_text("hello\n")
    (d / "notazip.zip").write_text("not a zip archive\n")
    (d / "bad.json").write_text("{not json")
    (d / "wrong_gains.json").write_text('{"kp": 1}\n')
    (d / "negative_zone.json").write_text('{"kp_pos": 2, "kp_vel": 3, "ki_vel": 1, "integral_zone": -0.02}\n')
    (d / "empty_gains.json").write_text('{}\n')
    (d / "extra_gain.json").write_text('{"kp_pos": 2, "kp_vel": 3, "ki_vel": 1, "extra": 2}\n')
    (d / "negative_gain.json").write_text('{"kp_pos": -2, "kp_vel": 3, "ki_vel": 1}\n')
    (d / "huge_gain.json").write_text('{"kp_pos": 2, "kp_vel": 3, "ki_vel": 1e308}\n')
    (d / "rolling_factor.json").write_text('{"kp_pos": 2, "kp_vel": 3, "ki_vel": 1, "rolling_factor": 7}\n')
    hexapod = load_preset("servo-hexapod").to_toml()  # its servos sit at 0.2992 rad at home
    (d / "traj_long_row.csv").write_text("t_s,x_mm\n0,1,2\n")
    (d / "traj_twice.csv").write_text("t_s,x_mm,x_mm\n0,1,2\n")
    (d / "traj_spaced.csv").write_text("\ufefft_s, x_mm\n0,1\n1,2\n")  # a byte-order mark and a space: taken
    in_line = "base_anchors = [" + ", ".join(f"[{0.02 * i}, 0.0, 0.0]" for i in range(6)) + "]\n"
    (d / "anchors_in_line.toml").write_text(re.sub(r"base_anchors = \[\n(?:  \[.*\],\n)+\]\n", in_line, hexapod))
    (d / "servo_turns.toml").write_text(re.sub(r"servo_angle_range = \[[^]]*\]", "servo_angle_range = [-6.0, 9.0]",
                                               hexapod))  # fmt: skip
    (d / "description_number.toml").write_text(hexapod.replace('description = "', 'description = 5\nx = "'))
    linear = load_preset("senilov2018").to_toml()
    (d / "linear_low_home.toml").write_text(re.sub(r"home_height = [0-9.e-]+", "home_height = 0.01", linear))
    (d / "narrow_range.toml").write_text(re.sub(r"servo_angle_range = \[[^]]*\]", "servo_angle_range = [0.3, 1.0]",
                                                hexapod))  # fmt: skip
    (d / "huge.toml").write_text(re.sub(r"home_height = [0-9.e-]+\n", "", re.sub(r"rod_length = [0-9.e-]+",
                                                                                "rod_length = 1e305", hexapod)))
    (d / "emptydir").mkdir()
    from stewart_gym.registry import POLICY_DIR

    shutil.copytree(POLICY_DIR / "balance" / "bundle", d / "bundle_balance")
    shutil.copytree(POLICY_DIR / "track" / "bundle", d / "bundle_track")
    (d / "unknown_cols.csv").write_text("t,a,b\n0,1,2\n1,2,3\n")
    (d / "text_values.csv").write_text("t_s,x_mm\n0,abc\n")
    (d / "nan_values.csv").write_text("t_s,x_mm\n0,nan\n")
    (d / "good.csv").write_text("t_s,x_mm,roll_deg\n0,0,0\n0.5,5,1\n1,10,2\n")
    (d / "existing.csv").write_text("keep me\n")
    (d / "run_done").mkdir()
    (d / "run_done" / "model.zip").write_text("a finished run\n")
    (d / "run_webcam").mkdir()  # a run trained with a camera preset (its model is never loaded here)
    (d / "run_webcam" / "model.zip").write_text("a finished run\n")
    (d / "run_webcam" / "config.yaml").write_text("options: {env_id: StewartBallBalance-v0}\nhyperparams:\n  "
                                                  "env_kwargs: {estimator: kalman, sensor: webcam30}\n")  # fmt: skip
    (d / "bad_ensemble").mkdir()
    (d / "bad_ensemble" / "ensemble.json").write_text('{"members": "members/0"}\n')
    _inputs_of_issue_57(d)
    bundle = d / "bad_bundle"
    bundle.mkdir()
    (bundle / "bundle.json").write_text(json.dumps({"kind": "onnx", "env_id": "StewartBallBalance-v0",
                                                    "action_mode": "pose", "obs_size": 16, "action_low": [-1, -1],
                                                    "action_high": [1, 1], "obs_mean": None, "obs_var": None,
                                                    "clip_obs": 10.0, "epsilon": 1e-8}))  # fmt: skip
    return d


def _inputs_of_issue_57(d: Path) -> None:
    """Files that are not what they claim, names that would escape, values the libraries would trip on."""
    import struct
    import zlib

    from stewart_gym.presets import load_preset
    from stewart_gym.registry import POLICY_DIR

    os.mkfifo(d / "fifo.toml")  # a named pipe: reading it would block until someone writes
    (d / "big.json").write_text(" " * (5 * 2**20) + "{}")  # larger than any configuration file
    hp = "StewartBallBalance-v0:\n  n_envs: 1\n"
    for name, text in {"lr_negative.yml": hp + "  learning_rate: -0.5\n", "batch_zero.yml": hp + "  batch_size: 0\n",
                       "net_arch_bad.yml": hp + "  policy_kwargs: {net_arch: [0, -3]}\n",
                       "duplicate.yml": hp + "  n_steps: 256\n  n_steps: 512\n",
                       "section_scalar.yml": "StewartBallBalance-v0: 5\n", "top_list.yml": "- 1\n- 2\n",
                       "gamma_high.yml": hp + "  gamma: 1.5\n", "epochs_frac.yml": hp + "  n_epochs: 2.5\n",
                       "lr_text.yml": hp + "  learning_rate: fast\n", "policy_kwargs_num.yml": hp + "  policy_kwargs: 5\n",
                       "log_std_nan.yml": hp + "  policy_kwargs: {log_std_init: .nan}\n"}.items():  # fmt: skip
        (d / name).write_text(text)
    sweep = "env: StewartBallBalance-v0\nalgo: ppo\nn_timesteps: 1000\n"
    (d / "sweep_lr.yaml").write_text(sweep + "search:\n  learning_rate: {grid: [-0.1, 0.001]}\n")
    (d / "sweep_batch.yaml").write_text(sweep + "batch_size: 0\n")
    (d / "sweep_dup.yaml").write_text(sweep + "n_timesteps: 2000\n")
    (d / "sweep_arch.yaml").write_text(sweep + "policy_kwargs: {net_arch: [0]}\n")
    camera = ('[camera]\n{camera}[markers]\nids = {ids}\ncentres_mm = {centres}\nsize_mm = {size}\n'
              '[ball]\n{ball}')  # fmt: skip
    square = "[[-125, 125], [125, 125], [125, -125], [-125, -125]]"
    cams = {"cam_ok": {}, "cam_min_text": {"camera": 'min_ball_px = "ten"\n'},
            "cam_min_negative": {"camera": "min_ball_px = -3\n"},
            "cam_id_range": {"ids": "[0, 1, 2, 99]"}, "cam_id_fraction": {"ids": "[0, 1.5, 2, 3]"},
            "cam_one_centre": {"centres": "[[0, 0], [0, 0], [0, 0], [0, 0]]"},
            "cam_collinear": {"centres": "[[-150, 0], [-50, 0], [50, 0], [150, 0]]"},
            "cam_hsv": {"ball": "hsv_low = [30, 120, 120]\nhsv_high = [25, 255, 255]\n"},
            "cam_resolution": {"camera": "resolution = [640.5, 480]\n"}, "cam_source": {"camera": 'source = ""\n'},
            "cam_fps": {"camera": "fps = 0\n"}, "cam_index": {"camera": "source = 1000\n"},
            "cam_size": {"size": "-5"}, "cam_radius": {"ball": "radius_mm = 1e9\n"}}  # fmt: skip
    for name, parts in cams.items():
        (d / f"{name}.toml").write_text(camera.format(**{"camera": "", "ids": "[0, 1, 2, 3]", "centres": square,
                                                         "size": "36", "ball": "", **parts}))  # fmt: skip
    (d / "cam_not_table.toml").write_text("camera = 3\n" + (d / "cam_ok.toml").read_text().replace("[camera]\n", ""))
    (d / "gains_twice.json").write_text('{"kp_pos": 2.0, "kp_pos": 200.0, "kp_vel": 3.0, "ki_vel": 3.0}')
    (d / "gains_long.json").write_text('{"kp_pos": 1' + "0" * 5000 + ', "kp_vel": 3, "ki_vel": 3}')
    (d / "lqr_huge.json").write_text('{"position_mm": 1e300, "velocity_mm_s": 40, "integral_mm_s": 6, "tilt": 0.1, '
                                     '"tilt_step": 0.002, "tilt_lag_s": 0.019}')  # fmt: skip
    (d / "cal_preset_digest.toml").write_text('geometry = "servo-hexapod"\ngeometry_sha256 = "' + "a" * 64 + '"\n'
                                              + "[[servo]]\n" * 6)  # fmt: skip
    from dataclasses import asdict

    from stewart_gym.control.gains import shipped_design

    handover = asdict(shipped_design("lqr-pid"))
    (d / "handover_stray.json").write_text(json.dumps({**handover, "foo": 1}))
    (d / "handover_no_pid.json").write_text(json.dumps({k: v for k, v in handover.items() if k != "pid"}))
    (d / "deep.json").write_text("[" * 50_000)
    (d / "deep.yml").write_text("StewartBallBalance-v0: " + "[" * 50_000)
    (d / "hp_device.yml").write_text("StewartBallBalance-v0:\n  n_envs: 2\n  device: cuda:7\n")
    (d / "gains_lead.json").write_text('{"kp_pos": 2.0, "kp_vel": 3.0, "ki_vel": 3.0, "feed_lead": 1e9}')

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    (d / "huge.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 50000, 50000, 8, 2, 0, 0, 0))
                                + chunk(b"IDAT", zlib.compress(b"\0" * 100)) + chunk(b"IEND", b""))  # fmt: skip
    geo = load_preset("servo-hexapod").to_toml()
    (d / "huge_plate.toml").write_text(geo.replace("plate_size = ", "plate_size = [1e300, 1e300]\n# was ", 1)
                                       if "plate_size = " in geo else geo + "plate_size = [1e300, 1e300]\n")  # fmt: skip
    (d / "name_control.toml").write_text(geo.replace('name = "servo-hexapod"', 'name = "a\\u0001b"'))
    (d / "name_long.toml").write_text(geo.replace('name = "servo-hexapod"', f'name = "{"x" * 200}"'))
    cal = 'geometry = "servo-hexapod"\n' + "[[servo]]\n" * 6
    (d / "cal_baud_negative.toml").write_text(cal + "[hardware]\nbaudrate = -9600\n")
    (d / "cal_baud_text.toml").write_text(cal + '[hardware]\nbaudrate = "fast"\n')
    (d / "cal_protocol.toml").write_text(cal + '[hardware]\nprotocol = "i2c"\n')
    (d / "cal_trim_typo.toml").write_text('geometry = "servo-hexapod"\n' + "[[servo]]\ntrim_uss = 3\n" * 6)
    (d / "residual_scale.yml").write_text("StewartBallBalance-v0:\n  n_envs: 1\n  env_wrapper:\n"
                                          "    - stewart_gym.sb3_models.ResidualAction: {residual: {base: lqr, scale: 5}}\n")
    (d / "rate_penalty_nan.yml").write_text("StewartBallBalance-v0:\n  n_envs: 1\n  env_kwargs: {rate_penalty: .nan}\n")
    (d / "batch_one.yml").write_text("StewartBallBalance-v0:\n  n_envs: 4\n  n_steps: 16\n  batch_size: 1\n")
    recipe = "StewartBallBalance-v0:\n  n_envs: 2\n  n_steps: 16\n  batch_size: 32\n"
    for name, line in {"n_envs_inf": "  n_timesteps: .inf\n", "normalize_key": "  normalize: {foo: 1}\n",
                       "policy_kwarg": "  policy_kwargs: {activation_fn: relu, squash_output: true}\n",
                       "ent_auto_ppo": "  ent_coef: auto\n", "buffer_kwargs": "  rollout_buffer_kwargs: {foo: 1}\n",
                       "randomize_text": "  env_kwargs: {randomize: 'no'}\n",
                       "diverges": "  vf_coef: 1.0e+300\n  n_timesteps: 256\n  env_kwargs: {backend: batched}\n"
                       }.items():  # fmt: skip
        (d / f"{name}.yml").write_text(recipe + line)
    (d / "tqc_quantiles.yml").write_text("StewartBallBalance-v0:\n  n_envs: 1\n  policy_kwargs: {n_quantiles: 2}\n")
    (d / "not_a_model").mkdir()
    (d / "not_a_model" / "model.zip").write_text("garbage\n")
    (d / "rollout_one.yml").write_text("StewartBallBalance-v0:\n  n_envs: 1\n  n_steps: 1\n  batch_size: 2\n")
    (d / "cal_other_build.toml").write_text('geometry = "memememe-liverpool"\n' + "[[servo]]\n" * 6)
    (d / "planar_unknown.toml").write_text("L1 = 1\nL2 = 1\nL3 = 1\ngamma = 1\nx1 = 1\nx2 = 1\ny2 = 1\np1 = 1\n"
                                           "p2 = 1\np3 = 1\nextra = 2\n")  # fmt: skip
    shipped = json.loads((POLICY_DIR / "balance" / "bundle" / "bundle.json").read_text())
    for name, change in {"bundle_obs_mean": {"obs_mean": shipped["obs_mean"][:3]}, "bundle_hz_zero": {"control_hz": 0},
                         "bundle_hz_text": {"control_hz": "fifty"}, "bundle_action_low": {"action_low": [-1.0]},
                         "bundle_var_negative": {"obs_var": [-1.0] * 12}, "bundle_clip_nan": {"clip_obs": math.nan},
                         "bundle_var_nan": {"obs_var": [math.nan] + [1.0] * 11},
                         "bundle_obs_size": {"obs_size": 11}, "bundle_env_id": {"env_id": "Foo-v0"},
                         "bundle_env_kwargs": {"env_kwargs": "oops"},
                         "bundle_unknown_field": {"note": "mine"}, "bundle_layout": {"observation_layout": 1},
                         "bundle_env_keyword": {"env_kwargs": {**shipped["env_kwargs"], "bogus": 1}},
                         "bundle_env_estimator": {"env_kwargs": {**shipped["env_kwargs"], "estimator": "magic"}},
                         "bundle_env_backend": {"env_kwargs": {**shipped["env_kwargs"], "backend": "foo"}},
                         "bundle_geometry_name": {"geometry": {**shipped["geometry"], "name": "desk-rect"}},
                         }.items():  # fmt: skip
        folder = d / name
        shutil.copytree(POLICY_DIR / "balance" / "bundle", folder)
        (folder / "bundle.json").write_text(json.dumps({**shipped, **change}))


# ------------------------------------------------------------------ good
def test_version() -> None:
    from stewart_gym import __version__

    proc = sg("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"stewart-gym {__version__}"


@pytest.mark.parametrize("command", ("",) + SUBCOMMANDS)
def test_help(command: str) -> None:
    proc = sg(*([command] if command else []), "--help")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: stewart-gym") and "Traceback" not in proc.stderr
    if command == "":
        assert "exit codes" in proc.stdout and all(c in proc.stdout for c in SUBCOMMANDS)
    if command == "assembly":  # --pose is a pose whose leg lengths are used, not leg lengths
        assert "whose leg lengths are used" in " ".join(proc.stdout.split())


GOOD = [
    # (arguments, exit code, text the output must contain)
    (["ik", "0", "0", "5", "3", "0", "0"], 0, "reachable"),  # the README's worked example
    (["ik", "0", "0", "30", "0", "0", "0"], 1, "unreachable"),
    (["ik", "--geometry", "senilov2018", "200", "0", "0", "0", "0", "0"], 1, "above the upper actuator limit"),
    (["ik", "--geometry", "senilov2018", "0", "0", "-300", "0", "0", "0"], 1, "not above its base anchor"),
    (["ik", "0", "0", "-5", "-3", "0", "0"], 0, "reachable"),  # negative numbers are values, not options
    (["ik", "-1e-3", "-.5", "0", "0", "0", "0"], 0, "reachable"),  # as users type them
    (["workspace", "--n", "20", "--samples", "2000"], 0, "reach from home"),
    (["trajectory"], 1, "first unreachable: sample"),  # source 001's 0.2 m circle leaves the stroke
    (["trajectory", "--radius", "20"], 0, "every sample is reachable"),
    (["trajectory", "--csv", "{files}/good.csv", "--geometry", "servo-hexapod"], 0, "3 samples"),
    (["sensitivity", "--n", "11", "--fd-samples", "5"], 0, "Jacobian vs finite differences"),
    (["conditioning", "--n", "11"], 0, "cond(J)"),
    (["planar"], 0, "pose(s)"),
    (["planar", "--sweep", "p2:0.5:12:31", "--json"], 0, '"sweep"'),
    (["trajectory", "--csv", "{files}/traj_spaced.csv", "--geometry", "servo-hexapod"], 0, "2 samples"),
    (["assembly", "--guesses", "200"], 0, "assembly modes"),
    (["assembly", "--guesses", "200", "--legs", "300", "300", "300", "300", "300", "300"], 0, "assembly modes"),
    (["evaluate", "--policy", "pid", "--episodes", "2", "--no-randomize"], 0, "success rate"),
]


@pytest.mark.slow
@pytest.mark.parametrize("args,code,text", GOOD, ids=[" ".join(a[:3]) for a, _, _ in GOOD])
def test_documented_commands(args: list[str], code: int, text: str, files: Path) -> None:
    proc = sg(*(a.format(files=files) for a in args))
    assert proc.returncode == code, proc.stdout + proc.stderr
    assert text in proc.stdout, proc.stdout
    assert "Traceback" not in proc.stderr


def test_ik_json_reports_pulses(tmp_path: Path) -> None:
    proc = sg("ik", "0", "0", "5", "3", "0", "0", "--json")
    out = json.loads(proc.stdout)
    assert proc.returncode == 0 and out["reachable"] is True and len(out["pulse_widths_us"]) == 6
    proc = sg("ik", "0", "0", "30", "0", "0", "0", "--json")
    out = json.loads(proc.stdout)
    assert proc.returncode == 1 and out["reachable"] is False and out["servo_angles_deg"] == [None] * 6


def test_huge_pose_is_unreachable_not_a_crash() -> None:
    proc = sg("ik", "1e308", "0", "0", "0", "0", "0", "--json")
    out = json.loads(proc.stdout)
    assert proc.returncode == 1 and out["reachable"] is False and "Traceback" not in proc.stderr
    proc = sg("ik", "0", "0", "0", "0", "0", "1e308")  # an angle beyond a whole turn is a mistake, not a pose
    assert proc.returncode == 1 and error_lines(proc) == [
        "error: stewart-gym ik: argument YAW_DEG: '1e308' must be in [-360, 360] (see stewart-gym ik --help)"]


def test_urdf_and_render(tmp_path: Path) -> None:
    proc = sg("urdf", "--out", str(tmp_path / "u"))
    assert proc.returncode == 0 and (tmp_path / "u" / "servo_hexapod.urdf").exists()
    proc = sg("render", "0", "0", "5", "3", "0", "0", "--out", str(tmp_path / "r.png"), "--width", "64",
              "--height", "48")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "r.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_workspace_of_a_linear_platform_finds_its_real_lowest_z() -> None:
    """The lowest z is where the platform reaches the base anchors' height (z = 20 − 250 mm), not the grid edge."""
    out = json.loads(sg("workspace", "--geometry", "senilov2018", "--n", "30", "--samples", "2000", "--json").stdout)
    hm = out["height_map"]
    assert hm["z_limited_by_grid"] is False
    assert -231.0 < hm["min_z_mm"] < -225.0


def test_trajectory_json_and_exit_codes(files: Path) -> None:
    proc = sg("trajectory", "--json")
    out = json.loads(proc.stdout)
    assert proc.returncode == 1 and out["first_unreachable"] == 0 and out["unreachable_fraction"] > 0.5


# ------------------------------------------------------------------- bad
DEV = "/dev/stewart-gym-no-such-port"
BAD = [
    # global
    [],
    ["bogus"],
    # ik
    ["ik"],
    ["ik", "0", "0", "0"],
    ["ik", "nan", "0", "0", "0", "0", "0"],
    ["ik", "0", "0", "0", "0", "0", "inf"],
    ["ik", "0", "0", "0", "0", "0", "1e308"],
    ["ik", "x", "0", "0", "0", "0", "0"],
    ["ik", "0", "0", "0", "0", "0", "0", "7"],
    ["ik", "0", "0", "0", "0", "0", "0", "--bogus"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "nope"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/missing.toml"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/binary.toml"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/bad.toml"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/partial.toml"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/emptydir"],
    # urdf
    ["urdf", "--geometry", "nope", "--out", "{tmp}/u"],
    ["urdf", "--out", "{files}/notes.txt"],
    ["urdf", "--out", "{files}/notes.txt/sub"],
    # mjcf
    ["mjcf"],
    ["mjcf", "--out", "{files}/notes.txt"],
    ["mjcf", "--geometry", "nope", "--out", "{tmp}/m.xml"],
    # render
    ["render", "0", "0", "0", "0", "0", "0"],
    ["render", "nan", "0", "0", "0", "0", "0", "--out", "{tmp}/x.png"],
    ["render", "0", "0", "50", "0", "0", "0", "--out", "{tmp}/x.png"],
    ["render", "0", "0", "0", "0", "0", "0", "--out", "{tmp}/x.jpg"],
    ["render", "0", "0", "0", "0", "0", "0", "--out", "{files}/emptydir"],
    ["render", "0", "0", "0", "0", "0", "0", "--out", "{tmp}/x.png", "--width", "0"],
    ["render", "0", "0", "999", "0", "0", "0", "--out", "{tmp}/x.png", "--geometry", "senilov2018"],
    # train
    ["train", "--backend", "ode"],
    ["train", "--timesteps", "0"],
    ["train", "--n-envs", "0"],
    ["train", "--vec-env", "threads"],
    ["train", "--backend", "batched", "--vec-env", "subproc", "--run-dir", "{tmp}/r"],  # its copies step together
    ["train", "--n-envs", "300", "--run-dir", "{tmp}/r"],  # 300 engines: the batched backend is for thousands
    ["train", "--max-minutes", "0"],
    ["train", "--max-minutes", "nan"],
    ["train", "--algo", "foo"],
    ["train", "--env", "Foo-v0"],
    ["train", "--seed", "-1"],
    ["train", "--hyperparams", "{files}/missing.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/bad.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/other.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/bad_reward.yml", "--run-dir", "{tmp}/r"],  # refused before the workers
    ["train", "--hyperparams", "{files}/env_kwargs_unknown.yml", "--run-dir", "{tmp}/r"],  # a keyword no env takes
    ["train", "--hyperparams", "{files}/env_kwargs_list.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/ppo_noise.yml", "--run-dir", "{tmp}/r"],  # action noise is for off-policy
    ["train", "--algo", "td3", "--hyperparams", "{files}/bad_noise.yml", "--run-dir", "{tmp}/r"],
    ["train", "--algo", "sac", "--hyperparams", "{files}/ppo_keys.yml", "--run-dir", "{tmp}/r"],  # PPO's keywords
    ["train", "--env", "StewartBallTrack-v0", "--hyperparams", "{files}/dwell_no_latch.yml", "--run-dir", "{tmp}/r"],
    ["train", "--run-dir", "{files}/notes.txt"],
    ["train", "--run-dir", "{files}/run_done"],
    ["train", "--resume", "{files}/emptydir", "--run-dir", "{tmp}/r"],
    ["train", "--geometry", "mathcad-micro", "--run-dir", "{tmp}/r"],  # a 30 mm plate cannot carry the ball
    ["train", "--geometry", "nope", "--run-dir", "{tmp}/r"],
    ["train", "--run-dir", "/proc/stewart-gym-run", "--max-minutes", "1"],  # /proc takes no new file
    # evaluate
    ["evaluate", "--policy", "nope"],
    ["evaluate", "--policy", "pid-kalman", "--trajectory", "figure8"],  # the balance env's target does not move
    ["evaluate", "--env", "StewartBallTrack-v0", "--trajectory", "spiral"],
    ["evaluate", "--episodes", "0"],
    ["evaluate", "--episodes", "-3"],
    ["evaluate", "--seed", "x"],
    ["evaluate", "--env", "Foo-v0"],
    ["evaluate", "--gif", "{files}/emptydir"],
    ["evaluate", "--plot", "{tmp}/x.txt"],
    ["evaluate", "--policy", "{files}/notazip.zip"],
    ["evaluate", "--policy", "{files}/bad.json"],
    ["evaluate", "--policy", "{files}/wrong_gains.json"],
    ["evaluate", "--policy", "{files}/negative_zone.json"],
    ["evaluate", "--policy", "{files}/emptydir"],
    ["evaluate", "--policy", "{files}/notes.txt"],
    ["evaluate", "--policy", "{files}/bad_bundle"],
    ["evaluate", "--policy", "pid", "--geometry", "mathcad-micro"],
    ["evaluate", "--backend", "bullet"],
    # export
    ["export"],
    ["export", "--policy", "nope", "--out", "{tmp}/b"],
    ["export", "--policy", "{files}/bad_ensemble", "--out", "{tmp}/b"],
    ["ensemble"],
    ["ensemble", "{files}/run_done", "--out", "{tmp}/e"],
    ["ensemble", "nope1", "nope2", "--out", "{tmp}/e"],
    ["ensemble", "{files}/bad_bundle", "{files}/bad_bundle", "--out", "{tmp}/e"],
    ["ensemble", "{files}/run_done", "{files}/run_done", "--out", "{files}/notes.txt"],
    ["train", "--checkpoint-freq", "0"],
    ["compare"],
    ["compare", "pid"],
    ["compare", "pid", "pid"],
    ["compare", "pid", "nope"],
    ["compare", "pid", "{files}/bad_bundle"],
    ["compare", "pid", "lqr", "--episodes", "1"],
    ["compare", "pid", "lqr", "--workers", "0"],
    ["evaluate", "--policy", "pid", "--workers", "0"],
    ["compare", "pid", "lqr", "--trajectory", "figure8"],
    ["compare", "pid", "lqr", "--geometry", "mathcad-micro"],
    ["compare", "shipped-camera", "{files}/run_webcam"],  # trained with different sensors: --sensor says which
    ["compare", "{files}/bundle_balance", "{files}/bundle_track"],  # trained for different tasks: --env says which
    ["compare", "{files}/bundle_balance", "{files}/./bundle_balance"],  # one policy, spelt twice
    ["compare", "shipped", "shipped-camera"],  # the touch panel (the default) against a camera
    ["export", "--env", "Foo-v0", "--out", "{tmp}/b"],
    ["export", "--out", "{files}/notes.txt"],
    # deploy: the arguments are checked before the port is opened
    ["deploy", "--backend", "mujoco", "--sensor", "panel", "--protocol", "line", "--port", "{files}/notes.txt"],
    ["deploy", "--rate", "-5"],
    ["deploy", "--rate", "0"],
    ["deploy", "--rate", "100000"],
    ["deploy", "--duration", "-1"],
    ["deploy", "--duration", "nan"],
    ["deploy", "--watchdog-ms", "0"],
    ["deploy", "--max-step-us", "-1"],
    ["deploy", "--baudrate", "5"],
    ["deploy", "--protocol", "foo", "--port", DEV],
    ["deploy", "--sensor", "camera", "--port", DEV],
    ["deploy", "--log", "{tmp}/l.csv"],  # no port
    ["deploy", "--policy", "nope", "--port", DEV],
    ["deploy", "--policy", "{files}/bad_bundle", "--port", DEV],
    ["deploy", "--policy", "{files}/emptydir", "--port", DEV],
    ["deploy", "--port", DEV, "--sensor", "panel", "--protocol", "maestro"],
    ["deploy", "--port", DEV, "--calibration", "{files}/missing.toml"],
    ["deploy", "--port", DEV, "--calibration", "{files}/bad.toml"],
    ["deploy", "--port", DEV, "--log", "{files}/existing.csv"],
    ["deploy", "--port", DEV, "--log", "{files}/emptydir"],
    ["deploy", "--port", DEV, "--trajectory", "circle"],
    ["deploy", "--port", DEV, "--geometry", "desk-rect"],  # no shipped policy for that build
    ["deploy", "--port", DEV, "--policy", "pid", "--geometry", "{files}/bad.toml"],
    # calibrate
    ["calibrate"],
    ["calibrate", "--step", "0", "--port", DEV],
    ["calibrate", "--port", DEV, "--out", "{files}/emptydir"],
    ["calibrate", "--port", DEV, "--calibration", "{files}/bad.toml"],
    ["calibrate", "--port", DEV, "--geometry", "senilov2018"],
    # analyses
    ["workspace", "--n", "0"],
    ["workspace", "--n", "2000"],
    ["workspace", "--pivot", "1e300", "0", "0"],
    ["conditioning", "--orientation", "30", "30", "30"],
    ["planar", "--p1", "1e300"],
    ["planar", "--sweep", "p2:1:1e300:10"],
    ["planar", "--sweep-plot", "{tmp}/s.png"],
    ["assembly", "--pose", "1e300", "0", "0", "0", "0", "0"],
    ["assembly", "--pose", "0", "0", "0", "1e6", "0", "0"],
    ["assembly", "--legs", "1e300", "1e300", "1e300", "1e300", "1e300", "1e300"],
    ["trajectory", "--csv", "{files}/traj_long_row.csv"],
    ["trajectory", "--csv", "{files}/traj_twice.csv"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/anchors_in_line.toml"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/servo_turns.toml"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/description_number.toml"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/linear_low_home.toml"],
    ["workspace", "--samples", "0"],
    ["workspace", "--orientation", "nan", "0", "0"],
    ["workspace", "--pivot", "0", "0"],
    ["workspace", "--z-step", "0"],
    ["workspace", "--plot", "{tmp}/x.txt"],
    ["workspace", "--geometry", "{files}/bad.toml"],
    ["trajectory", "--csv", "{files}/missing.csv"],
    ["trajectory", "--csv", "{files}/unknown_cols.csv"],
    ["trajectory", "--csv", "{files}/text_values.csv"],
    ["trajectory", "--csv", "{files}/nan_values.csv"],
    ["trajectory", "--csv", "{files}/binary.csv"],
    ["trajectory", "--radius", "nan"],
    ["trajectory", "--samples", "0"],
    ["sensitivity", "--geometry", "senilov2018"],
    ["sensitivity", "--step-deg", "0"],
    ["conditioning", "--threshold", "-1"],
    ["planar", "--geometry", "{files}/missing.toml"],
    ["planar", "--geometry", "{files}/planar_partial.toml"],
    ["planar", "--L1", "-1"],
    ["planar", "--gamma", "inf"],
    ["planar", "--sweep", "p9:1:2:3"],
    ["planar", "--sweep", "p2:1:2"],
    ["assembly", "--legs", "1", "2", "3"],
    ["assembly", "--legs", "-1", "-1", "-1", "-1", "-1", "-1"],
    ["assembly", "--guesses", "0"],
    ["assembly", "--geometry", "servo-hexapod", "--legs", "300", "300", "300", "300", "300", "300"],
    ["planar", "--L1", "9"],
    ["ik", "--geometry", "", "0", "0", "0", "0", "0", "0"],  # (an empty path is the current folder)
    ["evaluate", "--geometry", " "],
    # demo
    ["demo", "--backend", "x"],
    # camera-check
    ["camera-check"],
    ["camera-check", "--camera-config", "{files}/missing.toml"],
    ["camera-check", "--camera-config", "{files}/notes.txt"],
    ["train", "--sensor", "lidar"],
    ["evaluate", "--sensor", "lidar"],
    ["deploy", "--sensor", "camera", "--port", "{files}/notes.txt"],
    ["deploy", "--camera-config", "{files}/notes.txt", "--port", "{files}/notes.txt"],
    # virtual-device
    ["virtual-device", "--protocol", "i2c"],
    ["virtual-device", "--drop-rate", "1.5"],
    ["virtual-device", "--latency-ms", "nan"],
    ["virtual-device", "--link", "{files}/notes.txt"],
    ["virtual-device", "--camera-stream", "{files}/notes.txt"],
    ["virtual-device", "--camera-stream", "{tmp}/p", "--backend", "mujoco"],
    ["virtual-device", "--camera-config-out", "{tmp}/camera.toml"],
    ["virtual-device", "--camera-stream", "{tmp}/p", "--camera-config-out", "{tmp}/camera.txt"],  # a camera config is TOML
    ["virtual-device", "--camera-stream", "{tmp}/p", "--camera-config-out", "{files}/emptydir"],
    ["virtual-device", "--geometry", "nope"],
    ["virtual-device", "--camera-stream", "{tmp}/p", "--camera-config-out", "{files}/notes.txt"],  # not replaced
    ["virtual-device", "--camera-stream", "{tmp}/no_folder/p"],
    ["virtual-device", "--link", "/proc/no_such_folder/board"],
    ["virtual-device", "--put-ball-back-after", "0.1"],
    ["virtual-device", "--put-ball-back-after", "3", "--leave-fallen-ball"],
    ["demo", "--episodes", "0"],
    ["evaluate", "--backend", "batched", "--gif", "{tmp}/x.gif"],  # refused before any episode: nothing to draw
    ["demo", "--out", "{files}/notes.txt"],
    # sweep (the file is checked before Ray starts), the estimator, the LQR
    ["sweep"],
    ["sweep", "{files}/missing.yaml"],
    ["sweep", "{files}/notes.txt"],
    ["sweep", "{files}/binary.toml"],
    ["sweep", "{files}/notes.txt", "--num-samples", "0"],
    ["sweep", "{files}/notes.txt", "--address", "nowhere"],
    ["evaluate", "--estimator", "particle"],
    ["export", "--policy", "lqr", "--estimator", "x", "--out", "{tmp}/b"],
    ["evaluate", "--policy", "lqr", "--geometry", "{files}/bad.toml"],
]
# Issue 57's classes: files that are not files, names that escape, hyperparameters only the library checked,
# resume mistakes, camera configs, numbers that pass the parser and break the work, bundles with a bad field.
POLICY_BALANCE = str(ROOT / "stewart_gym" / "policies" / "balance")
BAD_57 = [
    # files that are not files: devices, pipes, folders, oversized files
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "/dev/zero"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/fifo.toml"],
    ["trajectory", "--csv", "/dev/zero"],
    ["trajectory", "--csv", "{files}/emptydir"],
    ["camera-check", "--camera-config", "/dev/zero"],
    ["camera-check", "--camera-config", "{files}/cam_ok.toml", "--image", "{files}/emptydir"],
    ["deploy", "--port", DEV, "--calibration", "/dev/zero"],
    ["train", "--hyperparams", "/dev/zero", "--run-dir", "{tmp}/r"],
    ["sweep", "/dev/zero"],
    ["planar", "--geometry", "/dev/zero"],
    ["evaluate", "--policy", "{files}/big.json"],
    ["calibrate", "--port", DEV, "--calibration", "/dev/zero"],
    ["virtual-device", "--calibration", "/dev/zero"],
    # names that escape or break the output
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/name_control.toml"],
    ["urdf", "--geometry", "{files}/name_long.toml", "--out", "{tmp}/u"],
    ["export", "--out", ""],
    ["ensemble", POLICY_BALANCE, POLICY_BALANCE + "_camera", "--out", ""],
    ["urdf", "--out", ""],
    ["mjcf", "--out", ""],
    ["demo", "--out", ""],
    # hyperparameters checked before training or Ray starts
    ["train", "--hyperparams", "{files}/lr_negative.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/batch_zero.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/net_arch_bad.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/duplicate.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/section_scalar.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/top_list.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/gamma_high.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/epochs_frac.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/lr_text.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/policy_kwargs_num.yml", "--run-dir", "{tmp}/r"],
    ["train", "--hyperparams", "{files}/log_std_nan.yml", "--run-dir", "{tmp}/r"],
    ["sweep", "{files}/sweep_lr.yaml"],
    ["sweep", "{files}/sweep_batch.yaml"],
    ["sweep", "{files}/sweep_dup.yaml"],
    ["sweep", "{files}/sweep_arch.yaml"],
    # resume mistakes
    ["train", "--resume", "shipped-residual", "--run-dir", "{tmp}/r"],  # an ensemble: resume one of its members
    ["train", "--algo", "sac", "--resume", POLICY_BALANCE, "--run-dir", "{tmp}/r"],
    ["train", "--resume", POLICY_BALANCE, "--run-dir", "{files}/run_done"],
    # camera configs
    *[["camera-check", "--camera-config", f"{{files}}/{name}.toml", "--image", "{files}/huge.png"]
      for name in ("cam_min_text", "cam_min_negative", "cam_id_range", "cam_id_fraction", "cam_one_centre",
                   "cam_collinear", "cam_hsv", "cam_resolution", "cam_source", "cam_fps", "cam_index", "cam_size",
                   "cam_radius")],  # fmt: skip
    ["camera-check", "--camera-config", "{files}/cam_ok.toml", "--image", "{files}/huge.png"],
    ["camera-check", "--camera-config", "{files}/cam_ok.toml", "--image", "{files}/notes.txt"],
    ["camera-check", "--camera-config", "{files}/cam_ok.toml", "--image", "/dev/zero"],
    # numbers that pass the parser and break the work
    ["evaluate", "--episodes", "10_000_000_000"],
    ["demo", "--episodes", "1000000"],
    ["compare", "pid", "lqr", "--episodes", "10000000"],
    ["evaluate", "--seed", "99999999999"],
    ["train", "--timesteps", "10_000_000_000"],
    ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/huge_plate.toml"],
    ["evaluate", "--policy", "pid", "--geometry", "{files}/huge_plate.toml"],
    ["workspace", "--orientation", "1e308", "0", "0"],
    ["deploy", "--port", DEV, "--calibration", "{files}/cal_baud_negative.toml"],
    ["deploy", "--port", DEV, "--calibration", "{files}/cal_baud_text.toml"],
    ["deploy", "--port", DEV, "--calibration", "{files}/cal_protocol.toml"],
    ["deploy", "--port", DEV, "--answer-timeout-ms", "0"],
    ["ensemble", POLICY_BALANCE, POLICY_BALANCE, "--out", "{tmp}/e"],
    ["planar", "--geometry", "{files}/planar_unknown.toml"],
    ["virtual-device", "--link", ""],
    ["virtual-device", "--link", "{tmp}/missing_dir/board"],
    # bundles with a field of the wrong size or type: refused as they load, before the port opens
    *[["deploy", "--port", DEV, "--policy", f"{{files}}/{name}"]
      for name in ("bundle_obs_mean", "bundle_hz_zero", "bundle_hz_text", "bundle_action_low", "bundle_var_negative",
                   "bundle_clip_nan", "bundle_obs_size")],  # fmt: skip
    ["evaluate", "--policy", "{files}/bundle_obs_mean"],
    ["calibrate", "--port", DEV, "--calibration", "{files}/cal_other_build.toml"],
    ["evaluate", "--policy", "{files}/bundle_env_id"],
    ["evaluate", "--policy", "{files}/bundle_env_kwargs"],
    ["evaluate", "--policy", "pid", "--episodes", "1", "--gif", "/proc/x.gif"],  # refused before the episode
    ["export", "--policy", "pid", "--out", "{files}/not_a_model"],  # a folder with a model: not a bundle's
]
DEVICE_FAILURES = {("deploy", DEV), ("calibrate", DEV)}  # a missing port is a device failure: exit 2
#: A few cases also run as real processes (the table runs in this process, through main([...]), for speed).
SUBPROCESS_SAMPLE = [["bogus"], ["ik", "nan", "0", "0", "0", "0", "0"], ["train", "--hyperparams", "{files}/bad.yml",
                     "--run-dir", "{tmp}/r"], ["deploy", "--policy", "nope", "--port", DEV],
                     ["ik", "0", "0", "0", "0", "0", "0", "--geometry", "/dev/zero"]]  # fmt: skip


@pytest.mark.parametrize("args", BAD + BAD_57, ids=[" ".join(a) or "(none)" for a in BAD + BAD_57])
def test_bad_input_is_one_error_line(args: list[str], files: Path, tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    code, out, err = cli(capfd, *(a.format(files=files, tmp=tmp_path) for a in args), cwd=tmp_path)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert code in (1, 2), code
    assert not list(tmp_path.glob("deploy_log*.csv")), "a refused deploy left a log behind"
    assert not (tmp_path / "r" / "config.yaml").exists(), "a refused training wrote its run folder"


@pytest.mark.parametrize("args", SUBPROCESS_SAMPLE, ids=[" ".join(a) for a in SUBPROCESS_SAMPLE])
def test_bad_input_in_a_real_process_is_one_error_line(args: list[str], files: Path, tmp_path: Path) -> None:
    proc = sg(*(a.format(files=files, tmp=tmp_path) for a in args), cwd=tmp_path, timeout=120)
    lines = error_lines(proc)
    assert "Traceback" not in proc.stderr and len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert proc.returncode in (1, 2), proc.returncode


WRONG_BLAME = [
    # (arguments, what the one line must name, what it must not)
    (["evaluate", "--policy", "pid", "--geometry", "{files}/missing.toml"], "missing.toml", "pid_gains.json"),
    (["evaluate", "--policy", "pid", "--geometry", "{files}/narrow_range.toml"],
     "narrow_range.toml: servo_angle_range: 0.3 rad (17.19°) to 1 rad (57.30°) does not hold the servo angles at home",
     "pid_gains.json"),
    (["evaluate", "--policy", "lqr", "--geometry", "{files}/narrow_range.toml"], "narrow_range.toml: servo_angle_range",
     "lqr.json"),
    (["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/narrow_range.toml"],
     "narrow_range.toml: servo_angle_range", "neutral_us"),
    (["evaluate", "--policy", "{files}/empty_gains.json"], "empty_gains.json: a PID's gains need kp_pos, kp_vel, ki_vel",
     "xx"),
    (["trajectory", "--csv", "{files}/traj_long_row.csv"], "traj_long_row.csv: line 2 has 3 field(s), the header 2",
     "xx"),
    (["conditioning", "--orientation", "30", "30", "30"], "no pose of the 61×61 grid is reachable", "nan"),
    (["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/anchors_in_line.toml"],
     "anchors_in_line.toml: base_anchors: the six anchors lie on one line or in one point", "xx"),
    (["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/servo_turns.toml"],
     "servo_turns.toml: servo_angle_range: a servo turns less than a whole turn", "min_us"),
    (["ik", "0", "0", "0", "0", "0", "0", "--geometry", "{files}/linear_low_home.toml"],
     "linear_low_home.toml: home_height: the home pose is unreachable", "xx"),
    (["evaluate", "--policy", "{files}/extra_gain.json"], "extra_gain.json: unknown field(s) ['extra']: a PID's gains "
     "are kp_pos", "__init__"),
    (["evaluate", "--policy", "{files}/negative_gain.json"], "negative_gain.json: kp_pos must be positive", "xx"),
    (["evaluate", "--policy", "{files}/huge_gain.json"], "ki_vel must be from 0 to 10000, got 1e+308", "xx"),
    (["evaluate", "--policy", "{files}/rolling_factor.json"], "rolling_factor must be above 0 and at most 1", "xx"),
    (["evaluate", "--policy", "{files}/negative_zone.json"], "integral_zone must be 0 (off) or more", "xx"),
    (["train", "--hyperparams", "{files}/section_scalar.yml", "--run-dir", "{tmp}/r"], "must be a mapping", "no section"),
    (["virtual-device", "--link", "{tmp}/missing_dir/board"], "missing_dir", "/dev/pts"),
    (["camera-check", "--camera-config", "{files}/cam_ok.toml", "--image", "{files}/emptydir"], "is a folder",
     "no such file"),
    (["calibrate", "--port", DEV, "--calibration", "{files}/cal_other_build.toml"], "--geometry", "the policy"),
    (["train", "--hyperparams", "{files}/lr_negative.yml", "--run-dir", "{tmp}/r"], "learning_rate", "Traceback"),
    (["train", "--hyperparams", "{files}/duplicate.yml", "--run-dir", "{tmp}/r"], "'n_steps' is given twice", "xx"),
    (["train", "--algo", "sac", "--resume", POLICY_BALANCE, "--run-dir", "{tmp}/r"], "is a PPO model", "xx"),
    (["camera-check", "--camera-config", "{files}/cam_id_range.toml"], "0…49", "xx"),
    (["deploy", "--port", DEV, "--policy", "{files}/bundle_obs_mean"], "obs_mean must be 12 finite numbers", "xx"),
    (["deploy", "--port", DEV, "--calibration", "{files}/cal_baud_text.toml"], "hardware.baudrate", "xx"),
    (["deploy", "--port", DEV, "--calibration", "{files}/cal_trim_typo.toml"], "cal_trim_typo.toml: servo[0]", "xx"),
    (["train", "--hyperparams", "{files}/residual_scale.yml", "--run-dir", "{tmp}/r"],
     "residual_scale.yml: StewartBallBalance-v0.env_wrapper: residual scale", "Traceback"),
    (["train", "--hyperparams", "{files}/rate_penalty_nan.yml", "--run-dir", "{tmp}/r", "--backend", "batched"],
     "rate_penalty_nan.yml: StewartBallBalance-v0.env_kwargs with --backend batched: rate_penalty must be a finite "
     "number, got nan",
     "Traceback"),
    (["train", "--hyperparams", "{files}/batch_one.yml", "--run-dir", "{tmp}/r"],
     "batch_one.yml: batch_size must be 2 or more, got 1", "Traceback"),
    (["train", "--hyperparams", "{files}/rollout_one.yml", "--run-dir", "{tmp}/r"], "n_steps 1 × n_envs 1", "Traceback"),
    (["train", "--hyperparams", "{files}/n_envs_inf.yml", "--run-dir", "{tmp}/r"],
     "n_envs_inf.yml: n_timesteps must be a whole number from 1 to 1e9, got inf", "Traceback"),
    (["train", "--hyperparams", "{files}/normalize_key.yml", "--run-dir", "{tmp}/r"], "normalize.foo", "Traceback"),
    (["train", "--hyperparams", "{files}/policy_kwarg.yml", "--run-dir", "{tmp}/r"],
     "policy_kwargs.squash_output is not taken for PPO", "activation_fn is"),
    (["train", "--hyperparams", "{files}/ent_auto_ppo.yml", "--run-dir", "{tmp}/r"], "SAC's and TQC's", "Traceback"),
    (["train", "--hyperparams", "{files}/buffer_kwargs.yml", "--run-dir", "{tmp}/r"], "rollout_buffer_kwargs",
     "Traceback"),
    (["train", "--hyperparams", "{files}/randomize_text.yml", "--run-dir", "{tmp}/r"],
     "randomize must be true or false, got 'no'", "Traceback"),
    (["train", "--resume", "{files}/not_a_model", "--run-dir", "{tmp}/r"], "not a Stable-Baselines3 model",
     "Traceback"),
    (["evaluate", "--policy", "{files}/bundle_env_id"], "made for env 'Foo-v0', which stewart_gym does not have",
     "Traceback"),
    (["evaluate", "--policy", "{files}/bundle_env_kwargs"], "bundle.json: env_kwargs must be a mapping", "Traceback"),
    (["export", "--policy", "pid", "--out", "{files}/not_a_model"], "holds other files (model.zip)", "Traceback"),
    (["evaluate", "--policy", "{files}/bundle_unknown_field"], "bundle.json: unknown field(s) ['note']", "Traceback"),
    (["evaluate", "--policy", "{files}/bundle_layout"], "bundle.json: the policy was exported for observation layout 1",
     "Traceback"),
    (["evaluate", "--policy", "{files}/bundle_env_keyword"],
     "bundle.json: env_kwargs: StewartBallBalance-v0 takes no keyword(s) ['bogus']", "Traceback"),
    (["evaluate", "--policy", "{files}/bundle_env_estimator"],
     "bundle.json: env_kwargs.estimator 'magic' is not the bundle's estimator 'kalman'", "Traceback"),
    (["evaluate", "--policy", "{files}/bundle_env_backend"], "bundle.json: env_kwargs.backend must be one of",
     "Traceback"),
    (["evaluate", "--policy", "{files}/bundle_geometry_name"],
     "bundle.json: geometry.name 'desk-rect' is not the name in geometry.toml ('servo-hexapod')", "Traceback"),
    (["train", "--algo", "tqc", "--hyperparams", "{files}/tqc_quantiles.yml", "--run-dir", "{tmp}/r"],
     "top_quantiles_to_drop_per_net (2) must be below policy_kwargs.n_quantiles (2)", "Traceback"),
    (["train", "--hyperparams", "{files}/diverges.yml", "--run-dir", "{tmp}/r"],
     "training diverged after 32 steps: the network gave NaN", "Traceback"),
    (["ik", "0", "0", "0", "0", "0", "0", "--geometry", "/dev/zero"], "not a regular file", "xx"),
    (["sweep", "{files}/sweep_lr.yaml"], "search.learning_rate", "xx"),
    (["compare", "pid", "lqr", "--episodes", "1e12"], "'1e12' must be at least 2 and at most 100000", "whole"),
    (["urdf", "--geometry", "{files}/huge.toml", "--out", "{tmp}/u"], "rod_length: 1e+305 m is larger than any build",
     "Traceback"),
    (["deploy", "--policy", "{files}/bundle_var_nan", "--port", "{files}/notes.txt"], "obs_var[0] is nan", "got 12"),
    (["deploy", "--port", "{files}/notes.txt", "--duration", "1"], "it is not a serial device: check --port",
     "Traceback"),
    (["deploy", "--twin", "{files}/notes.txt", "--sensor", "panel", "--protocol", "line", "--port", "{files}/notes.txt"],
     "--twin describes the simulated plant: it needs --sensor sim", "notes.txt"),
    (["render", "0", "0", "0", "0", "0", "0", "--out", "{files}/notes.txt/x.png"], "notes.txt is a file, not a folder",
     "notes.txt: "),  # (said once)
    (["deploy", "--port", "{files}/emptydir", "--duration", "1"], "emptydir: it is not a serial device: check --port",
     "Errno"),  # (pyserial's own text names the port and the errno again)
    (["sysid", "{files}/good.csv", "--out", "{tmp}/t.toml", "--marker-height-mm", "-1e9"], "'-1e9' must be in [0, 20]",
     "expected one argument"),
    (["ik", "-inf", "0", "0", "0", "0", "0"], "'-inf' is not a finite number", "required"),
    (["deploy", "--seed", "3", "--sensor", "panel", "--protocol", "line", "--port", "{files}/notes.txt"],
     "--seed sets the simulated plant: it needs --sensor sim", "serial device"),
    (["deploy", "--no-randomize", "--sensor", "panel", "--protocol", "line", "--port", "{files}/notes.txt"],
     "--no-randomize sets the simulated plant: it needs --sensor sim", "serial device"),
    (["camera-check", "--camera-config", "{files}/cam_not_table.toml", "--image", "{files}/emptydir"],
     "cam_not_table.toml: [camera] must be a table", "Traceback"),
    (["evaluate", "--policy", "{files}/gains_twice.json"], "gains_twice.json: 'kp_pos' is given twice", "Traceback"),
    (["evaluate", "--policy", "{files}/gains_long.json"], "gains_long.json: a number too long to read", "Traceback"),
    (["evaluate", "--policy", "{files}/lqr_huge.json"], "position_mm must be from 1e-06 to 1e+06, got 1e+300",
     "Traceback"),
    (["evaluate", "--policy", "{files}/gains_lead.json"], "feed_lead must be from 0 to 1 s", "Traceback"),
    (["evaluate", "--policy", "{files}/deep.json"], "deep.json: nested too deeply to read", "RecursionError"),
    (["train", "--hyperparams", "{files}/deep.yml", "--run-dir", "{tmp}/r"], "deep.yml: nested too deeply to read",
     "RecursionError"),
    (["train", "--hyperparams", "{files}/hp_device.yml", "--run-dir", "{tmp}/r"],
     "hp_device.yml: ['device'] is set by train itself (device: the CPU", "not PPO hyperparameters"),
    (["evaluate", "--policy", "{files}/handover_stray.json"], "a hand-over design: unknown field(s) ['foo']",
     "'lqr': {"),
    (["evaluate", "--policy", "{files}/handover_no_pid.json"], "a hand-over design: missing pid", "'lqr': {"),
    (["deploy", "--policy", "pid", "--sensor", "sim", "--calibration", "{files}/cal_preset_digest.toml"],
     "its geometry_sha256 is not that of the preset 'servo-hexapod'", "which is not there"),
]  # fmt: skip


@pytest.mark.parametrize("args,named,not_named", WRONG_BLAME, ids=[" ".join(a[:3]) for a, _, _ in WRONG_BLAME])
def test_an_error_names_what_is_wrong(args: list[str], named: str, not_named: str, files: Path, tmp_path: Path,
                                     capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    code, _, err = cli(capfd, *(a.format(files=files, tmp=tmp_path) for a in args), cwd=tmp_path)
    assert code in (1, 2) and named in err and not_named not in err, err


def test_a_geometry_name_never_leaves_the_output_folder_or_breaks_the_xml(tmp_path: Path,
                                                                         capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """A name with ``../`` writes its URDFs inside ``--out`` (the file name is made safe); one with XML's special
    characters writes URDF and MJCF that parse, with the name as given."""
    import xml.etree.ElementTree as ET

    from stewart_gym.presets import load_preset

    toml = load_preset("servo-hexapod").to_toml()
    for name in ("../escaped", '"<&>--x'):
        geo = tmp_path / "geo.toml"
        geo.write_text(toml.replace('name = "servo-hexapod"', f"name = {json.dumps(name)}"))
        out = tmp_path / "out"
        code, _, err = cli(capfd, "urdf", "--geometry", str(geo), "--out", str(out), cwd=tmp_path)
        assert code == 0, err
        written = sorted(out.glob("*.urdf"))
        assert len(written) == 2 and not list(tmp_path.glob("*.urdf")) and not (tmp_path / "escaped.urdf").exists()
        for path in written:
            assert ET.parse(path).getroot().get("name").startswith(name)
        code, _, err = cli(capfd, "mjcf", "--geometry", str(geo), "--out", str(tmp_path / "m.xml"), cwd=tmp_path)
        assert code == 0 and ET.parse(tmp_path / "m.xml").getroot().get("model") == name, err
        shutil.rmtree(out)


@pytest.mark.parametrize("args", [["ik", "0", "0", "0", "0", "0", "0"], ["evaluate", "--policy", "pid"],
                                  ["deploy", "--policy", "pid"]])  # fmt: skip
def test_an_unknown_option_is_named_by_its_subcommand(args: list[str]) -> None:
    """An option the subcommand does not take points at that subcommand's help, not the top-level one."""
    proc = sg(*args, "--no-such-option", "7")
    lines = error_lines(proc)
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr
    assert lines[0] == (f"error: stewart-gym {args[0]}: unrecognized arguments: --no-such-option 7 "
                        f"(see stewart-gym {args[0]} --help)")  # fmt: skip


def test_bad_input_table_is_large() -> None:
    assert len(BAD) >= 60 and {a[0] for a in BAD if a} >= set(SUBCOMMANDS)
    assert len(BAD_57) >= 60


def test_demo_on_a_build_without_a_shipped_policy_is_one_error_line_and_writes_nothing(tmp_path: Path) -> None:
    proc = sg("demo", "--geometry", "senilov2018", "--out", str(tmp_path / "demo"), cwd=tmp_path)
    lines = error_lines(proc)
    assert proc.returncode == 1 and len(lines) == 1 and "no shipped policy" in lines[0] and "senilov2018" in lines[0]
    assert lines[0].endswith("train one for it: stewart-gym train --env StewartBallBalance-v0 --geometry senilov2018")
    assert not (tmp_path / "demo").exists()
    proc = sg("evaluate", "--policy", "shipped-residual", "--geometry", "memememe-liverpool", cwd=tmp_path)
    lines = error_lines(proc)  # the residual: the recipe that trains one, by the name train takes
    assert proc.returncode == 1 and len(lines) == 1 and lines[0].endswith(
        "stewart-gym train --env StewartBallBalance-v0 --geometry memememe-liverpool --hyperparams ppo_residual")


def test_a_missing_port_is_a_device_failure(tmp_path: Path) -> None:
    for cmd in ("deploy", "calibrate"):
        proc = sg(cmd, "--port", DEV, "--duration" if cmd == "deploy" else "--step", "1", cwd=tmp_path)
        assert proc.returncode == 2 and error_lines(proc)[0].startswith("error: cannot open"), proc.stderr


def test_debug_shows_the_traceback() -> None:
    proc = sg("--debug", "ik", "0", "0", "0", "0", "0", "0", "--geometry", "nope")
    assert proc.returncode == 1 and "Traceback" in proc.stderr and "error: " in proc.stderr
    proc = sg("ik", "0", "0", "0", "0", "0", "0", "--geometry", "nope", "--debug")
    assert proc.returncode == 1 and "Traceback" in proc.stderr


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
@pytest.mark.parametrize("how", ["cause", "context"])
def test_a_stop_that_a_library_wraps_is_still_a_stop(signum: int, how: str, capsys: pytest.CaptureFixture) -> None:
    """A signal that lands inside a C extension's import (onnxruntime's, while deploy loads a bundle) comes back
    as that library's ``ImportError: initialization failed``, with the stop as its cause or context: still one
    ``error: stopped by …`` line and 128 + the signal's number, never a traceback."""
    import argparse

    from stewart_gym.cli.common import run
    from stewart_gym.errors import Stopped

    def load_library(args: argparse.Namespace) -> int:
        try:
            raise Stopped(signum, signal.Signals(signum).name) if signum != signal.SIGINT else KeyboardInterrupt
        except KeyboardInterrupt as stop:
            if how == "cause":
                raise ImportError("initialization failed") from stop
            raise ImportError("initialization failed")  # noqa: B904 (as a C extension raises it)

    assert run(load_library, argparse.Namespace()) == 128 + signum
    err = capsys.readouterr().err
    assert err.startswith("error: stopped by") and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_inside_an_import_while_the_parser_loads_is_one_line(signum: int, monkeypatch: pytest.MonkeyPatch,
                                                                   capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    """Ctrl-C while the commands' modules load (before any command runs) can land in a C extension's
    initialisation (scipy's), which reports ``ImportError: initialization failed`` with the stop behind it:
    one ``error: stopped by …`` line and 128 + the signal's number. Here the import system raises it, as the
    C extension does; the command line is the real one."""
    import importlib.abc
    import sys

    import stewart_gym.cli.analysis  # noqa: F401 (loaded, so that it can be taken away)
    from stewart_gym import cli
    from stewart_gym.errors import Stopped

    class InterruptedExtension(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):  # noqa: ANN001, ANN201
            if name != "stewart_gym.cli.analysis":
                return None
            try:
                raise Stopped(signum, signal.Signals(signum).name) if signum != signal.SIGINT else KeyboardInterrupt
            except KeyboardInterrupt as stop:
                raise ImportError("initialization failed") from stop

    monkeypatch.delitem(sys.modules, "stewart_gym.cli.analysis")
    monkeypatch.delattr(cli, "analysis")
    monkeypatch.setattr(sys, "meta_path", [InterruptedExtension(), *sys.meta_path])
    assert cli.main(["ik", "0", "0", "0", "0", "0", "0"]) == 128 + signum
    err = capsys.readouterr().err
    assert err.startswith("error: stopped by") and len(err.splitlines()) == 1, err
    with pytest.raises(ImportError):  # --debug keeps the traceback
        cli.main(["--debug", "ik", "0", "0", "0", "0", "0", "0"])


def test_an_error_with_no_stop_behind_it_is_still_a_bug(capsys: pytest.CaptureFixture) -> None:
    import argparse

    from stewart_gym.cli.common import run

    def broken(args: argparse.Namespace) -> int:
        try:
            raise ValueError("inner")
        except ValueError:
            raise ImportError("initialization failed")  # noqa: B904

    with pytest.raises(ImportError):
        run(broken, argparse.Namespace())


# ------------------------------------------------------- deploy, end to end
def deploy(device: FakeDevice, *args: str, cwd: Path, lines=None, **faults) -> tuple[subprocess.CompletedProcess, bytes]:
    """``stewart-gym deploy --port DEVICE ARGS`` against a :class:`~conftest.Board` of the protocol the arguments
    name (maestro by default), which answers position queries and, on the line protocol, sends ``lines(t)``."""
    protocol = args[args.index("--protocol") + 1] if "--protocol" in args else "maestro"
    board = Board(device, protocol, lines=lines, **faults)
    proc = sg("deploy", "--port", device.path, *args, cwd=cwd, timeout=120)
    return proc, board.stop()


def test_deploy_runs_a_bundle_at_the_rate_it_was_trained_at(device: FakeDevice, tmp_path: Path) -> None:
    """A bundle made for 25 Hz runs at 25 Hz unless ``--rate`` says otherwise (it ran at 50 Hz, with a note)."""
    assert sg("export", "--policy", "pid", "--out", str(tmp_path / "b"), cwd=tmp_path).returncode == 0
    meta = json.loads((tmp_path / "b" / "bundle.json").read_text())
    (tmp_path / "b" / "bundle.json").write_text(json.dumps({**meta, "control_hz": 25}))
    proc, _ = deploy(device, "--policy", str(tmp_path / "b"), "--sensor", "sim", "--duration", "2", "--log",
                     str(tmp_path / "log.csv"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0 and "note: the policy was trained at" not in proc.stdout, proc.stdout + proc.stderr
    assert 48 <= len((tmp_path / "log.csv").read_text().splitlines()) - 1 <= 52  # 2 s at 25 Hz
    proc, _ = deploy(device, "--policy", str(tmp_path / "b"), "--sensor", "sim", "--duration", "1", "--rate", "50",
                     "--log", str(tmp_path / "log50.csv"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0 and "note: the policy was trained at 25 Hz and runs at 50 Hz" in proc.stdout


@pytest.mark.parametrize("protocol", ["maestro", "ssc32", "line"])
def test_deploy_dry_run_prints_its_summary(protocol: str, device: FakeDevice, tmp_path: Path) -> None:
    """The documented dry run: exits 0 and prints the summary with the simulated ball's final error."""
    proc, data = deploy(device, "--protocol", protocol, "--sensor", "sim", "--duration", "2", "--log",
                        str(tmp_path / "log.csv"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "completed; simulated ball" in proc.stdout and "servos homed: confirmed by the board" in proc.stdout
    assert "Traceback" not in proc.stderr
    rows = (tmp_path / "log.csv").read_text().splitlines()
    assert 95 <= len(rows) - 1 <= 105
    if protocol == "maestro":
        pulses = maestro_frames(data)
        assert len(pulses) >= 100 and np.all((pulses >= 1000) & (pulses <= 2000))


def test_deploy_with_the_panel_on_the_line_protocol(device: FakeDevice, tmp_path: Path) -> None:
    """The documented hardware run: the sketch reports the panel (B x,y in mm) and the policy acts on it."""
    proc, data = deploy(device, "--protocol", "line", "--sensor", "panel", "--duration", "1", "--log",
                        str(tmp_path / "l.csv"), cwd=tmp_path, lines=lambda t: b"B 40.0,-20.0\n")  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    import csv

    rows = list(csv.DictReader((tmp_path / "l.csv").open()))
    assert len(rows) == 50 and sum(int(r["stale"]) for r in rows) < 5
    # the panel's reading is the observed position: the shipped policy runs behind the Kalman observer, whose
    # estimate of a ball read still at 40 mm for 1 s comes within 0.1 mm of it (measured: 0.02 mm) while the
    # policy tilts the plate (the filter's bias state learns that the ball does not roll)
    assert abs(float(rows[-1]["obs0"]) * 0.15 - 0.040) < 1e-4
    assert data.count(b"W ") >= 50


def test_evaluate_runs_the_track_env_on_the_trajectory_asked_for(capfd: pytest.CaptureFixture) -> None:
    """``evaluate --trajectory``: the figures printed are those of the Python evaluation on that trajectory (one
    seed, the PID + Kalman), not of the circle the PID gets by default."""
    from stewart_gym.evaluation import evaluate
    from stewart_gym.registry import load_for_evaluation

    _, policy, env_kwargs = load_for_evaluation("pid-kalman", "StewartBallTrack-v0")
    direct = {t: evaluate("StewartBallTrack-v0", policy, episodes=1, seed=3, env_kwargs={**env_kwargs,
                          "trajectory": t})["rms_error_mm"] for t in ("circle", "waypoints")}  # fmt: skip
    assert abs(direct["circle"] - direct["waypoints"]) > 0.05
    proc = sg_in(capfd, "evaluate", "--policy", "pid-kalman", "--env", "StewartBallTrack-v0", "--trajectory", "waypoints",
              "--episodes", "1", "--seed", "3", "--json")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout)["rms_error_mm"] == pytest.approx(direct["waypoints"], abs=1e-6)


@pytest.mark.slow
def test_shipped_residual_answers_pushes_with_its_base_s_fast_release(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """``compare shipped-residual COPY --env StewartBallDisturbance-v0``: ``shipped-residual`` names the balance
    residual on the pushes env too, and its base gives a pushed ball back to the LQR at once (``release_mm_s``,
    ``push_release_mm``): on seed 0 it holds the pushed ball over a millimetre closer than the same networks whose
    run configurations lack the two fields (off, as before them)."""
    from stewart_gym.registry import POLICY_DIR

    old = tmp_path / "without_fast_release"
    shutil.copytree(POLICY_DIR / "balance_residual", old, ignore=shutil.ignore_patterns("bundle"))
    for config in old.glob("members/*/config.yaml"):
        text = config.read_text()
        assert "release_mm_s: 60.0\n      push_release_mm: 5.0\n" in text
        config.write_text(text.replace("      release_mm_s: 60.0\n      push_release_mm: 5.0\n", ""))
    proc = sg_in(capfd, "compare", "shipped-residual", str(old), "--env", "StewartBallDisturbance-v0", "--episodes", "2",
              "--json")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    assert out["env_id"] == "StewartBallDisturbance-v0"
    rms = {name: got["per_episode"]["rms_mm"][0] for name, got in out["policies"].items()}
    assert rms["shipped-residual"] < rms[str(old)] - 1.0, rms


@pytest.mark.slow
def test_compare_evaluates_each_policy_as_evaluate_does_and_pairs_them(capfd: pytest.CaptureFixture) -> None:
    """``compare A B C``: each policy's figures are those ``evaluate`` prints for it on the same seeds (here two
    at a time, in worker processes), and A is paired with B and with C, each verdict agreeing with its interval
    (a lower error is better, a higher success rate is better). The text output names each pair's verdicts."""
    policies = ("pid-kalman", "lqr", "pid")
    proc = sg_in(capfd, "compare", *policies, "--episodes", "10", "--seed", "2", "--workers", "2", "--json")
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout)
    assert list(got["policies"]) == list(policies) and (got["episodes"], got["seed"]) == (10, 2)
    assert (got["env_id"], got["geometry"], got["backend"], got["sensor"]) == (
        "StewartBallBalance-v0", "servo-hexapod", "pybullet", "panel")
    alone = sg_in(capfd, "evaluate", "--policy", "lqr", "--episodes", "10", "--seed", "2", "--json")
    assert alone.returncode == 0, alone.stderr[-2000:]
    for key in ("success_rate", "rms_error_mm", "final_error_mm", "settling_time_s", "settled_pulse_p2p_us"):
        assert got["policies"]["lqr"][key] == pytest.approx(json.loads(alone.stdout)[key], rel=1e-9)
    rows = got["paired"]
    assert {(r["a"], r["b"]) for r in rows} == {("pid-kalman", "lqr"), ("pid-kalman", "pid")}
    assert {r["metric"] for r in rows} == {"success_rate", "rms_error_mm", "final_error_mm", "settling_time_s"}
    settled = {b: sum(x is not None and y is not None for x, y in
                      zip(*(got["policies"][p]["per_episode"]["settling_s"] for p in ("pid-kalman", b))))
               for b in ("lqr", "pid")}  # fmt: skip
    for r in rows:
        lower_is_better = r["metric"] != "success_rate"
        pairs = settled[r["b"]] if r["metric"] == "settling_time_s" else 10
        expected = (f"too few episodes ({pairs} < 10)" if pairs < 10 else "tie" if r["low"] <= 0 <= r["high"] else
                    "better" if (r["high"] < 0) == lower_is_better else "worse")  # fmt: skip
        assert r["verdict"] == expected and r["low"] <= r["difference"] <= r["high"]
    # the PID + Kalman holds the ball closer than the plain PID on every seed of this draw, so better
    rms = {r["b"]: r for r in rows if r["metric"] == "rms_error_mm"}
    assert rms["pid"]["verdict"] == "better"
    text = sg_in(capfd, "compare", "pid-kalman", "pid", "--episodes", "3", "--workers", "1")
    assert text.returncode == 0, text.stderr[-2000:]
    assert "pid-kalman − pid, seed by seed" in text.stdout and "RMS error (last 5 s)" in text.stdout
    assert re.search(r"RMS error .* too few episodes \(3 < 10\)", text.stdout)  # three seeds decide nothing


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ["StewartBallBalance-v0", "StewartBallTrack-v0"])
def test_evaluate_split_over_processes_prints_the_figures_of_one_process(env_id: str, capfd: pytest.CaptureFixture) -> None:
    """``evaluate --workers 2`` runs the episodes in two processes (the first two in one, the third in the
    other) and prints the same JSON, every figure and per-episode value alike, as ``--workers 1``: each episode
    depends only on its seed (and, in the settling test, on its index among all the episodes)."""
    runs = [sg_in(capfd, "evaluate", "--policy", "pid-kalman", "--env", env_id, "--episodes", "3", "--seed", "5",
               "--workers", str(w), "--json") for w in (1, 2)]  # fmt: skip
    for proc in runs:
        assert proc.returncode == 0, proc.stderr[-2000:]
    one, split = (json.loads(proc.stdout) for proc in runs)
    assert split == one and len(one["per_episode"]["final_mm"]) == 3
    assert (one["settling_time_s"] is None) == (env_id == "StewartBallTrack-v0")
    if env_id == "StewartBallBalance-v0":  # compare splits each policy's episodes too: 4 processes, 2 per policy
        proc = sg_in(capfd, "compare", "pid-kalman", "lqr", "--episodes", "3", "--seed", "5", "--workers", "4", "--json")
        assert proc.returncode == 0 and "4 processes at a time" in proc.stderr, proc.stderr[-2000:]
        both = json.loads(proc.stdout)["policies"]
        assert {k: v for k, v in both["pid-kalman"].items() if k in one} == {k: v for k, v in one.items()
                                                                             if k in both["pid-kalman"]}  # fmt: skip
        assert both["lqr"]["per_episode"] != both["pid-kalman"]["per_episode"]


@pytest.mark.slow
def test_compare_labels_a_column_by_the_end_of_its_path(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """``compare``'s table labels a policy given by path with the path's last part, more of it where two would
    read alike, and says which path each label stands for; ``--json`` keeps the paths as given."""
    gains = [tmp_path / "a" / "deep" / "folder" / "gains.json", tmp_path / "b" / "gains.json"]
    for path in gains:
        path.parent.mkdir(parents=True)
        shutil.copyfile(ROOT / "stewart_gym" / "policies" / "pid_kalman_gains.json", path)
    proc = sg_in(capfd, "compare", "pid-kalman", *map(str, gains), "--episodes", "2", "--workers", "1")
    assert proc.returncode == 0, proc.stderr[-2000:]
    header = next(line for line in proc.stdout.splitlines() if "pid-kalman" in line and "gains" in line)
    assert header.split() == ["pid-kalman", "folder/gains.json", "b/gains.json"], header
    assert f"folder/gains.json: {gains[0]}" in proc.stdout and f"b/gains.json: {gains[1]}" in proc.stdout
    assert "pid-kalman − folder/gains.json, seed by seed" in proc.stdout and str(tmp_path) not in header


@pytest.mark.slow
@pytest.mark.parametrize(("processes", "after_s"), [(2, 0.0), (3, 0.0), (4, 0.0), (4, 1.5)])
def test_ctrl_c_in_a_compare_split_over_processes_is_one_line(processes: int, after_s: float, tmp_path: Path) -> None:
    """A terminal's Ctrl-C reaches the command and its worker processes alike: before the workers start (the
    command and multiprocessing's resource tracker: 2 processes), as the first starts (3), while both still load
    (4, at once) or while they evaluate: one line, exit 130, no worker's traceback, no process left."""
    proc = subprocess.Popen([sys.executable, "-m", "stewart_gym", "compare", "pid", "lqr", "--episodes", "40",
                             "--workers", "2"], cwd=tmp_path, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "STEWART_GYM_PROGRESS_S": "86400"})  # fmt: skip

    def group() -> list[str]:
        return subprocess.run(["pgrep", "-g", str(proc.pid)], capture_output=True, text=True).stdout.split()

    try:
        deadline = time.monotonic() + 120
        while len(group()) < processes:
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1][-2000:]
            time.sleep(0.05)
        time.sleep(after_s)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        lines = [line for line in err.splitlines() if line.strip()]
        assert proc.returncode == 130 and lines == ["error: stopped by Ctrl-C (SIGINT) before the command finished"], err
        deadline = time.monotonic() + 10
        while group() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert group() == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="signals cannot be blocked on this system")
def test_a_ctrl_c_while_the_workers_start_is_kept_for_after() -> None:
    """A Ctrl-C in the moments the evaluation's workers start (when they must not take it yet) stops the command as
    soon as they have started: it is not lost, which would run the whole comparison after it."""
    from stewart_gym.experiments import ctrl_c_held_while_workers_start

    reached = []
    with pytest.raises(KeyboardInterrupt):
        with ctrl_c_held_while_workers_start():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            reached.append("the tasks are submitted")
    assert reached == ["the tasks are submitted"]
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())


def test_paired_verdict_reads_the_interval_in_the_metrics_direction() -> None:
    from stewart_gym.evaluation import paired_verdict

    assert paired_verdict("rms_error_mm", -0.3, -0.1) == "better"
    assert paired_verdict("settling_time_s", 0.1, 0.3) == "worse"
    assert paired_verdict("success_rate", 0.02, 0.1) == "better"  # more successes
    assert paired_verdict("success_rate", -0.1, -0.02) == "worse"
    assert paired_verdict("final_error_mm", -0.1, 0.1) == paired_verdict("success_rate", 0.0, 0.0) == "tie"
    assert paired_verdict("settling_time_s", float("nan"), float("nan")) == "–"
    # two episodes of one sign are no verdict: the interval is only their smallest and largest difference
    assert paired_verdict("rms_error_mm", 0.07, 1.08, pairs=2) == "too few episodes (2 < 10)"
    assert paired_verdict("rms_error_mm", 0.07, 1.08, pairs=10) == "worse"


@pytest.mark.slow
def test_evaluate_writes_gif_and_plot(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """The GIF plays the 10 s episode in real time: 25 frames a second, each of them rendered (every other 50 Hz
    step), none thrown away."""
    import imageio.v3 as iio

    gif = tmp_path / "figures" / "gif" / "pid.gif"  # in folders made as it writes
    proc = sg_in(capfd, "evaluate", "--policy", "pid", "--episodes", "1", "--gif", str(gif), "--plot",
                 str(tmp_path / "pid.png"))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert gif.read_bytes()[:6] == b"GIF89a" and (tmp_path / "pid.png").stat().st_size > 10_000
    meta = iio.immeta(gif)
    assert iio.improps(gif).shape[0] == 250 and meta["duration"] == pytest.approx(40, abs=1)


@pytest.mark.parametrize("args", [["mjcf", "--out", "new/servo.xml"], ["sensitivity", "--plot", "new/s.png"],
                                  ["evaluate", "--policy", "pid", "--episodes", "1", "--plot", "new/deeper/p.png"]])
def test_a_file_written_into_a_folder_not_made_yet_is_written(args: list[str], tmp_path: Path,
                                                               capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """An output in a folder that does not exist yet: the folder is made as the file is written (the work done
    is not lost to "no such file or directory" at the end)."""
    code, _, err = cli(capfd, *args, cwd=tmp_path)
    assert code == 0 and "error" not in err, err
    assert (tmp_path / args[-1]).stat().st_size > 1000


@pytest.mark.parametrize("args", [["evaluate", "--policy", "pid", "--episodes", "100", "--gif", "/proc/new/x.gif"],
                                  ["mjcf", "--out", "/proc/servo.xml"], ["sensitivity", "--plot", "/proc/s.png"]])
def test_an_output_where_no_file_can_be_made_is_refused_before_the_work(args: list[str], tmp_path: Path,
                                                                       capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """``/proc`` takes no new file, though root's permissions call it writable: refused before the work (a
    hundred episodes ran first, then writing failed), naming the file and the folder."""
    if not Path("/proc").is_dir():
        pytest.skip("no /proc on this system")
    code, _, err = cli(capfd, *args, cwd=tmp_path)
    lines = err.strip().splitlines()
    assert code == 1 and len(lines) == 1, err
    expected = (f"error: {args[-1]}: /proc takes no new files (no such file or directory); choose a folder you can "
                "write in") if os.access("/proc", os.W_OK) else "no permission to write in /proc"  # fmt: skip
    assert expected in lines[0], err


def test_deploy_pid_leaves_no_temporary_folder(device: FakeDevice, tmp_path: Path) -> None:
    before = set(Path(tempfile.gettempdir()).glob("stewart_pid_*"))
    proc, _ = deploy(device, "--policy", "pid", "--duration", "0.5", "--log", str(tmp_path / "l.csv"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert set(Path(tempfile.gettempdir()).glob("stewart_pid_*")) == before


def test_deploy_lqr_pid_drives_the_servos_within_their_limits(device: FakeDevice, tmp_path: Path) -> None:
    """``--policy lqr-pid`` (the LQR handing over to the PID + Kalman) deploys like the PID and the LQR: it holds
    the simulated ball within the success radius and every pulse sent is within the channel limits."""
    proc, data = deploy(device, "--policy", "lqr-pid", "--sensor", "sim", "--duration", "1", "--log",
                        str(tmp_path / "l.csv"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    held = re.search(r"simulated ball ([\d.]+) mm from the centre", proc.stdout)
    assert held and float(held.group(1)) < 10.0, proc.stdout
    pulses = maestro_frames(data)
    assert len(pulses) >= 40 and np.all((pulses >= 500) & (pulses <= 2500)), pulses.min()


@pytest.mark.slow
def test_deploy_never_overwrites_a_log(device: FakeDevice, tmp_path: Path) -> None:
    proc, _ = deploy(device, "--duration", "0.2", cwd=tmp_path)
    logs = list((tmp_path / "out").glob("deploy_log_*.csv"))
    assert proc.returncode == 0 and len(logs) == 1, proc.stderr
    proc, data = deploy(device, "--duration", "0.2", "--log", str(logs[0]), cwd=tmp_path)
    assert proc.returncode == 1 and "--overwrite" in proc.stderr and data == b""  # refused before the port opened
    proc, _ = deploy(device, "--duration", "0.2", "--log", str(logs[0]), "--overwrite", cwd=tmp_path)
    assert proc.returncode == 0


@pytest.mark.slow
def test_unplug_in_sim_mode_exits_2(device: FakeDevice, tmp_path: Path) -> None:
    drain = Board(device)
    proc = subprocess.Popen([sys.executable, "-m", "stewart_gym", "deploy", "--port", device.path, "--duration", "30",
                             "--log", str(tmp_path / "l.csv")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=tmp_path)  # fmt: skip
    deadline = time.monotonic() + 60
    while len(drain.data) < 24 * 20 and time.monotonic() < deadline:  # wait until it runs
        time.sleep(0.05)
    drain.stop()
    device.unplug()
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2, out + err
    assert "device failure" in out and "Traceback" not in err
    assert len((tmp_path / "l.csv").read_text().splitlines()) > 20  # the log is kept


@pytest.mark.slow
def test_deploy_track_bundle_follows_a_moving_target(device: FakeDevice, tmp_path: Path,
                                                     capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    proc = sg_in(capfd, "export", "--policy", "shipped", "--env", "StewartBallTrack-v0", "--out", str(tmp_path / "tb"))
    assert proc.returncode == 0, proc.stderr
    proc, _ = deploy(device, "--policy", str(tmp_path / "tb"), "--trajectory", "circle", "--duration", "1", "--log",
                     str(tmp_path / "l.csv"), cwd=tmp_path)  # fmt: skip  (trained on all three; the circle moves at once)
    assert proc.returncode == 0 and "tracking a circle target" in proc.stdout, proc.stderr
    import csv

    rows = list(csv.DictReader((tmp_path / "l.csv").open()))
    targets = np.array([[float(r["obs4"]), float(r["obs5"])] for r in rows])
    assert np.ptp(targets, axis=0).max() > 0.01  # the target in the observation moves


@pytest.mark.slow
def test_deploy_of_a_mixed_trajectory_tracker_says_which_trajectory_its_seed_drew(device: FakeDevice,
                                                                                 tmp_path: Path) -> None:
    """The shipped residual tracker was trained on mixed trajectories: deploy follows the one --seed draws."""
    from stewart_gym.envs.tasks.track import TrackTask

    drawn = set()
    for seed in ("0", "1", "2", "3"):
        proc, _ = deploy(device, "--policy", "shipped-residual", "--env", "StewartBallTrack-v0", "--seed", seed,
                         "--rate", "10", "--duration", "0.3", "--log", str(tmp_path / f"l{seed}.csv"),
                         cwd=tmp_path)  # fmt: skip
        assert proc.returncode == 0, proc.stdout + proc.stderr
        task = TrackTask(trajectory="mixed")
        task.reset(np.random.default_rng(int(seed)), None)  # what deploy draws for this seed
        assert f"tracking a {task.current_trajectory} target" in proc.stdout
        drawn.add(task.current_trajectory)
    assert len(drawn) > 1


def test_deploy_runs_the_shipped_balance_residual_whose_bundle_averages_six_networks(device: FakeDevice,
                                                                                     tmp_path: Path) -> None:
    proc, sent = deploy(device, "--policy", "shipped-residual", "--rate", "10", "--duration", "0.5", "--log",
                        str(tmp_path / "l.csv"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert len((tmp_path / "l.csv").read_text().splitlines()) >= 4 and sent


@pytest.mark.slow
def test_export_of_the_shipped_track_policy_is_the_track_network(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    from stewart_gym.hardware.export import BundlePolicy
    from stewart_gym.registry import POLICY_DIR

    track = sg_in(capfd, "export", "--policy", "shipped", "--env", "StewartBallTrack-v0", "--out", str(tmp_path / "t"))
    assert track.returncode == 0
    assert sg_in(capfd, "export", "--policy", "shipped", "--out", str(tmp_path / "b")).returncode == 0
    obs = np.random.default_rng(0).uniform(-1, 1, (50, 12))
    track, balance = BundlePolicy(tmp_path / "t"), BundlePolicy(tmp_path / "b")
    assert track.env_id == "StewartBallTrack-v0" and balance.env_id == "StewartBallBalance-v0"
    assert np.allclose(track(obs), BundlePolicy(POLICY_DIR / "track" / "bundle")(obs), atol=1e-5)
    assert not np.allclose(track(obs), balance(obs), atol=1e-3)


# --------------------------------------------------------------- calibrate
def test_calibrate_saves_trims_port_and_protocol(device: FakeDevice, tmp_path: Path) -> None:
    from stewart_gym.calibration import ServoCalibration, hardware_settings

    drain = Drain(device)
    out = tmp_path / "not made yet" / "cal.toml"  # the trims found are not lost to a missing folder
    proc = sg("calibrate", "--port", device.path, "--protocol", "maestro", "--step", "0.1", "--out", str(out),
              stdin="+\n+\n+\nn\n-\nx\nq\n", cwd=tmp_path)  # fmt: skip
    data = drain.stop()
    assert proc.returncode == 0, proc.stderr
    assert "unknown key 'x'" in proc.stdout
    assert "home angle of each horn on servo-hexapod: 17.1° above horizontal" in proc.stdout  # what to trim to
    hw = hardware_settings(out)
    assert hw == {"port": device.path, "protocol": "maestro"}
    cal = ServoCalibration.from_toml(out, "servo-hexapod")
    assert np.allclose(cal.neutral_us - 1500, [0.3, -0.1, 0, 0, 0, 0], atol=1e-9)
    text = out.read_text()
    assert "99999" not in text and "00000" not in text, text  # no float noise such as 1084.999999 or 0.30000000004
    last = maestro_frames(data)[-1]
    assert np.allclose(last, np.round(cal.neutral_us * 4) / 4)  # left at the new neutral, not the old one
    # the file drives deploy with no more options
    board = Board(device)
    assert sg("deploy", "--calibration", str(out), "--duration", "0.2", "--log", str(tmp_path / "l.csv"),
              cwd=tmp_path).returncode == 0  # fmt: skip
    board.stop()
    # a second calibration does not replace the first's hand-set trims unless asked, and asks before the port opens
    drain = Drain(device)
    again = sg("calibrate", "--port", device.path, "--protocol", "maestro", "--out", str(out), stdin="q\n",
               cwd=tmp_path)  # fmt: skip
    assert drain.stop() == b"" and again.returncode == 1 and error_lines(again) == [
        f"error: {out} exists; give another name or --overwrite"], again.stderr
    assert out.read_text() == text



def test_calibrate_keeps_a_relative_port_as_a_full_path(device: FakeDevice, tmp_path: Path) -> None:
    """``--port out/board`` (the tutorial's link to the virtual board) is written as its full path: the port of
    ``deploy --calibration out/cal.toml`` run from another folder (it was taken from that folder)."""
    from stewart_gym.calibration import hardware_settings

    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "board").symlink_to(device.path)
    drain = Drain(device)
    proc = sg("calibrate", "--port", "out/board", "--protocol", "maestro", "--out", "cal.toml", stdin="q\n",
              cwd=tmp_path)  # fmt: skip
    drain.stop()
    assert proc.returncode == 0, proc.stderr
    assert hardware_settings(tmp_path / "cal.toml")["port"] == str(tmp_path / "out" / "board")


def test_calibrate_keeps_every_limit_within_any_servos_pulses(device: FakeDevice, tmp_path: Path) -> None:
    """A build whose servos travel further than hobby servos' pulses express (here 1500 µs ± 1,170 µs), trimmed
    200 µs down: the file calibrate writes holds limits within 400–2600 µs, so that it reads back and drives
    deploy (it could not be read back before)."""
    from stewart_gym.calibration import PULSE_LIMITS_US, ServoCalibration
    from stewart_gym.presets import load_preset

    wide = tmp_path / "wide.toml"
    wide.write_text(re.sub(r"servo_angle_range = \[[^]]*\]", "servo_angle_range = [-2.0, 2.6]",
                           load_preset("servo-hexapod").to_toml()))  # fmt: skip
    drain = Drain(device)
    out = tmp_path / "cal.toml"
    proc = sg("calibrate", "--geometry", str(wide), "--port", device.path, "--protocol", "maestro", "--step", "50",
              "--out", str(out), stdin="-\n-\n-\n-\nq\n", cwd=tmp_path)  # fmt: skip
    drain.stop()
    assert proc.returncode == 0, proc.stderr
    cal = ServoCalibration.from_toml(out)
    assert cal.neutral_us[0] == pytest.approx(1300.0) and cal.neutral_us[1] == pytest.approx(1500.0)
    lowest, highest = PULSE_LIMITS_US
    untrimmed = ServoCalibration.default(str(wide))  # what calibrate starts from
    assert untrimmed.min_us.min() == lowest and untrimmed.max_us.max() == highest
    assert cal.min_us.min() == lowest and cal.max_us.max() == highest  # bounded there, not beyond
    assert np.all(cal.min_us < cal.neutral_us) and np.all(cal.neutral_us < cal.max_us)
    board = Board(device)
    deploy = sg("deploy", "--policy", "pid", "--geometry", str(wide), "--calibration", str(out), "--duration", "0.2",
                "--log", str(tmp_path / "l.csv"), cwd=tmp_path)  # fmt: skip
    board.stop()
    assert deploy.returncode == 0, deploy.stderr

# ------------------------------------------- pose- and pulse-mode policies
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["pose", "pulse"])
def test_policies_trained_in_pose_or_pulse_mode_work_after_training(mode: str, device: FakeDevice,
                                                                     tmp_path: Path,
                                                                     capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """train → evaluate → export → deploy, all through the command line, keep the action mode."""
    hp = tmp_path / "hp.yml"
    hp.write_text(f"StewartBallBalance-v0:\n  n_envs: 1\n  n_timesteps: 128\n  normalize: true\n  policy: MlpPolicy\n"
                  f"  env_kwargs:\n    action_mode: {mode}\n  n_steps: 64\n  batch_size: 32\n  n_epochs: 1\n"
                  "  policy_kwargs:\n    net_arch: [16, 16]\n")  # fmt: skip
    # a temporary directory too long for a forkserver's socket: the evaluation worker is spawned instead
    run, tmp = tmp_path / "run", tmp_path / ("tmp" + "-" * max(0, 90 - len(str(tmp_path))))
    tmp.mkdir()
    proc = sg("train", "--hyperparams", str(hp), "--run-dir", str(run), "--eval-freq", "64", "--eval-episodes", "1",
              "--no-progress", "--no-tensorboard", cwd=tmp_path, env={"TMPDIR": str(tmp)})  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert not list(tmp.glob("SB3-*"))  # SB3's logger left no folder in the temporary directory
    metrics = json.loads((run / "metrics.json").read_text())
    assert isinstance(metrics["last_eval"]["timesteps"], int) and isinstance(metrics["last_eval"]["wall_s"], float)
    assert "not a git checkout" in (run / "git.txt").read_text() or "stewart_gym" in (run / "git.txt").read_text()
    proc = sg_in(capfd, "evaluate", "--policy", str(run), "--episodes", "1", "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["episodes"] == 1
    proc = sg_in(capfd, "export", "--policy", str(run), "--out", str(tmp_path / "bundle"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((tmp_path / "bundle" / "bundle.json").read_text())
    assert meta["action_mode"] == mode and len(meta["action_low"]) == 6
    proc, data = deploy(device, "--policy", str(tmp_path / "bundle"), "--duration", "1", "--log",
                        str(tmp_path / "l.csv"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    import csv

    rows = list(csv.DictReader((tmp_path / "l.csv").open()))
    assert sum(int(r["held"]) for r in rows) < len(rows)  # the policy's actions reach the servos
    assert "action5" in rows[0]  # six actions logged
    proc = sg_in(capfd, "train", "--hyperparams", str(hp), "--run-dir", str(run), cwd=tmp_path)
    assert proc.returncode == 1 and "--overwrite" in proc.stderr  # a finished run is not overwritten


@pytest.mark.slow
def test_a_run_trains_the_same_network_with_its_envs_in_process_or_in_worker_processes(
        tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """``train --vec-env subproc`` and the default (``dummy``) give the same weights and statistics, bit for
    bit: the choice is one of speed only (bench/bench_train.py). The evaluations during training are the same
    episodes in each run of a seed, so the learning curves agree too."""
    import csv
    import hashlib
    import pickle
    import zipfile

    hp = tmp_path / "hp.yml"
    hp.write_text("StewartBallBalance-v0:\n  n_envs: 2\n  n_timesteps: 512\n  normalize: true\n  policy: MlpPolicy\n"
                  "  env_kwargs: {randomize: true, estimator: kalman}\n  n_steps: 128\n  batch_size: 64\n"
                  "  n_epochs: 2\n  policy_kwargs: {net_arch: [16, 16]}\n")  # fmt: skip
    found = {}
    for vec_env in ("dummy", "subproc"):
        run = tmp_path / vec_env
        proc = sg_in(capfd, "train", "--hyperparams", str(hp), "--run-dir", str(run), "--vec-env", vec_env, "--seed", "4",
                  "--eval-freq", "256", "--eval-episodes", "2", "--no-progress", "--no-tensorboard",
                  cwd=tmp_path)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        with zipfile.ZipFile(run / "model.zip") as z:
            weights = hashlib.sha256(z.read("policy.pth")).hexdigest()
        stats = pickle.loads((run / "vecnormalize.pkl").read_bytes())
        curve = [(row["timesteps"], row["mean_reward"]) for row in csv.DictReader((run / "eval.csv").open())]
        found[vec_env] = weights, stats.obs_rms.mean, stats.ret_rms.var, curve
        assert json.loads((run / "metrics.json").read_text())["timesteps"] == 512 and len(curve) == 2
    (w_a, mean_a, var_a, curve_a), (w_b, mean_b, var_b, curve_b) = found["dummy"], found["subproc"]
    assert w_a == w_b and np.array_equal(mean_a, mean_b) and np.array_equal(var_a, var_b) and curve_a == curve_b


@pytest.mark.slow
def test_a_policy_that_observes_the_error_integral_keeps_it_from_training_to_deploy(
        device: FakeDevice, tmp_path: Path, capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """``integral: true``: train → evaluate → export → deploy through the command line; the bundle records it,
    deploy builds the 14-value observation (the integral in the last two, summed while the ball is near the
    centre); a bundle with a malformed flag is refused before the port opens."""
    hp = tmp_path / "hp.yml"
    hp.write_text("StewartBallBalance-v0:\n  n_envs: 1\n  n_timesteps: 128\n  normalize: true\n  policy: MlpPolicy\n"
                  "  env_kwargs: {estimator: kalman, integral: true}\n  n_steps: 64\n  batch_size: 32\n"
                  "  n_epochs: 1\n  policy_kwargs:\n    net_arch: [16, 16]\n")  # fmt: skip
    run, bundle = tmp_path / "run", tmp_path / "bundle"
    proc = sg_in(capfd, "train", "--hyperparams", str(hp), "--run-dir", str(run), "--eval-freq", "64",
                 "--eval-episodes", "1", "--no-progress", "--no-tensorboard", cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    proc = sg_in(capfd, "evaluate", "--policy", str(run), "--episodes", "1", "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = sg_in(capfd, "export", "--policy", str(run), "--out", str(bundle), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((bundle / "bundle.json").read_text())
    assert meta["integral"] is True and meta["obs_size"] == 14 and meta["estimator"] == "kalman"
    proc, _ = deploy(device, "--policy", str(bundle), "--sensor", "sim", "--duration", "2", "--log",
                     str(tmp_path / "l.csv"), cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    import csv

    rows = list(csv.DictReader((tmp_path / "l.csv").open()))
    assert "obs13" in rows[0] and "obs14" not in rows[0]
    assert any(float(r["obs12"]) != 0.0 for r in rows)  # the simulated ball starts near the centre: it sums
    (bundle / "bundle.json").write_text(json.dumps({**meta, "integral": "yes"}))
    proc, data = deploy(device, "--policy", str(bundle), "--sensor", "sim", "--duration", "1", cwd=tmp_path)
    assert proc.returncode != 0 and proc.stderr.startswith("error: ") and "integral" in proc.stderr and not data


def test_training_records_the_package_revision_not_the_working_directory(tmp_path: Path) -> None:
    """git.txt names the revision of the stewart_gym source, even when training runs inside another repository."""
    from stewart_gym.training import _git_revision

    other = tmp_path / "other_repo"
    other.mkdir()
    subprocess.run(["git", "init", "-q"], cwd=other, check=True)
    cwd = os.getcwd()
    try:
        os.chdir(other)
        text = _git_revision()
    finally:
        os.chdir(cwd)
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    assert (head and head in text) or "not a git checkout" in text


def test_a_refused_export_leaves_no_folder(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """Gains that are refused, or a build the PID cannot run on, are one line and write no ``--out`` folder."""
    from stewart_gym.presets import load_preset

    gains = tmp_path / "gains.json"
    gains.write_text(json.dumps({"kp_pos": math.nan, "kp_vel": 3.0}))
    geometry = tmp_path / "geo.toml"
    text = load_preset("servo-hexapod").to_toml()
    geometry.write_text(re.sub(r"servo_angle_range = \[[^]]*\]", "servo_angle_range = [-300.0, 600.0]", text))
    assert "servo_angle_range = [-300.0, 600.0]" in geometry.read_text()
    for args, out in ((["--policy", str(gains)], tmp_path / "b1"),
                      (["--policy", "pid", "--geometry", str(geometry)], tmp_path / "b2")):  # fmt: skip
        code, _, err = cli(capfd, "export", *args, "--out", str(out), cwd=tmp_path)
        assert code == 1 and err.startswith("error: ") and err.count("\n") == 1, err
        assert not out.exists()


def test_a_gains_files_max_tilt_that_is_not_used_is_said(tmp_path: Path, capfd: pytest.CaptureFixture,
                                                          caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    """The PID's tilt at action ±1 is the env's; a gains file that sets another is noted (on stderr, through the
    package's logger, which pytest captures in-process) and runs."""
    gains = json.loads((ROOT / "stewart_gym" / "policies" / "pid_gains.json").read_text())
    for name, max_tilt in (("same.json", gains["max_tilt"]), ("other.json", 0.3)):
        (tmp_path / name).write_text(json.dumps({**gains, "max_tilt": max_tilt}))
        code, out, err = cli(capfd, "evaluate", "--policy", str(tmp_path / name), "--episodes", "1", cwd=tmp_path)
        assert code == 0 and "success rate" in out, err
        said = [ln for ln in err.splitlines() + caplog.messages if "max_tilt" in ln]
        caplog.clear()
        if name == "same.json":
            assert not said, err
        else:
            assert said == [f"note: {tmp_path / name}: max_tilt 0.3 rad is not used: the controller's tilt at action "
                            "±1 is the env's, 0.174533 rad on 'servo-hexapod' (a PID's max_tilt must match the env's)"]


def test_assembly_reports_progress_in_lines_into_a_pipe() -> None:
    """Piped, a long analysis prints progress lines as the other commands do, not a terminal's ``\\r`` bar."""
    proc = sg("assembly", "--guesses", "4000", env={"STEWART_GYM_PROGRESS_S": "0.1"})
    assert proc.returncode == 0 and "\r" not in proc.stderr, proc.stderr
    assert all(ln.startswith("assembly modes: ") and " batches (" in ln for ln in proc.stderr.splitlines()), proc.stderr


def test_a_link_that_leads_nowhere_is_refused_before_the_work(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """An output through a dangling link, a link loop or a name too long for any file system: one line before the
    episodes run (each was found only when the GIF was written, and the episodes' figures were lost)."""
    (tmp_path / "dangling.gif").symlink_to(tmp_path / "gone" / "x.gif")
    (tmp_path / "loop1").symlink_to(tmp_path / "loop2")
    (tmp_path / "loop2").symlink_to(tmp_path / "loop1")
    (tmp_path / "run").symlink_to(tmp_path / "gone")
    cases = [(["evaluate", "--policy", "pid", "--episodes", "100", "--gif", "dangling.gif"],
              "dangling.gif is a link to "),
             (["evaluate", "--policy", "pid", "--episodes", "100", "--gif", "loop1/x.gif"], "leads back to itself"),
             (["evaluate", "--policy", "pid", "--episodes", "100", "--plot", "x/" + "a" * 300 + "/p.png"],
              "is 300 bytes long; a file or folder name takes at most 255"),
             (["train", "--run-dir", "run/inside"], "run is a link to ")]  # fmt: skip
    for args, said in cases:
        code, out, err = cli(capfd, *args, cwd=tmp_path)
        lines = err.strip().splitlines()
        assert code == 1 and len(lines) == 1 and said in lines[0] and "episodes" not in out, (args, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling.gif", "loop1", "loop2", "run"]  # nothing made


def test_a_file_the_run_writes_that_is_a_folder_is_refused_before_training(tmp_path: Path,
                                                                          capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    (tmp_path / "r" / "vecnormalize.pkl").mkdir(parents=True)
    code, _, err = cli(capfd, "train", "--timesteps", "64", "--run-dir", "r", cwd=tmp_path)
    assert code == 1 and err.strip() == "error: r/vecnormalize.pkl is a folder, where the run writes a file; remove " \
                                        "it or give another --run-dir", err  # fmt: skip
    assert [p.name for p in (tmp_path / "r").iterdir()] == ["vecnormalize.pkl"]


def test_files_saved_with_a_byte_order_mark_are_read(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """Notepad's "UTF-8 with BOM": a geometry (TOML) and PID gains (JSON) read as without it."""
    from stewart_gym.presets import load_preset

    bom = "\ufeff"
    (tmp_path / "g.toml").write_text(bom + load_preset("servo-hexapod").to_toml(), encoding="utf-8")
    shipped = Path(__file__).resolve().parents[2] / "stewart_gym" / "policies" / "pid_gains.json"
    (tmp_path / "gains.json").write_text(bom + shipped.read_text(), encoding="utf-8")
    code, out, err = cli(capfd, "ik", "0", "0", "0", "0", "0", "0", "--geometry", "g.toml", "--json", cwd=tmp_path)
    assert code == 0 and json.loads(out)["reachable"], err
    code, _, err = cli(capfd, "export", "--policy", "gains.json", "--out", "b", cwd=tmp_path)
    assert code == 0 and (tmp_path / "b" / "bundle.json").is_file(), err


def test_a_bundles_description_named_as_the_policy_is_its_bundle(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """``--policy b/bundle.json`` is the bundle ``b`` (it was read as PID gains: "unknown field(s) ['action_high',
    …]")."""
    assert cli(capfd, "export", "--policy", "pid", "--out", "b", cwd=tmp_path)[0] == 0
    code, out, err = cli(capfd, "export", "--policy", "b/bundle.json", "--out", "c", cwd=tmp_path)
    assert code == 0, err
    assert json.loads((tmp_path / "c" / "bundle.json").read_text()) == json.loads((tmp_path / "b" /
                                                                                  "bundle.json").read_text())


def test_a_demo_file_that_is_a_folder_is_refused_before_the_episodes(tmp_path: Path,
                                                                     capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    """(The GIF went into ``out/demo.gif/demo.gif``, and the command said it wrote ``out/demo.gif``.)"""
    (tmp_path / "o" / "demo.gif").mkdir(parents=True)
    code, out, err = cli(capfd, "demo", "--episodes", "10", "--out", "o", cwd=tmp_path)
    said = "error: o/demo.gif is a folder, where the demo writes a file; remove it or give another --out"
    assert code == 1 and "evaluating" not in out and err.strip() == said, err
    assert list((tmp_path / "o" / "demo.gif").iterdir()) == []


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full (a device that is always full) here")
def test_a_full_disk_says_what_to_do(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    (tmp_path / "full.png").symlink_to("/dev/full")
    code, _, err = cli(capfd, "render", "0", "0", "0", "0", "0", "0", "--out", "full.png", cwd=tmp_path)
    assert code == 1 and err.strip() == "error: no space left on device (free some space, or write elsewhere)", err


def test_path_messages_name_what_is_wrong(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """A link's folder that is a file was called a folder that does not exist; a pair angle far out of range
    suggests ``angle_unit``; ``render --out '~/x.png'`` writes where the check looked (imageio expanded ``~``)."""
    (tmp_path / "notes.txt").write_text("")
    code, _, err = cli(capfd, "virtual-device", "--link", "notes.txt/board", cwd=tmp_path)
    assert code == 1 and err.strip() == "error: --link notes.txt/board: notes.txt is a file, not a folder; link " \
                                        "elsewhere", err  # fmt: skip
    (tmp_path / "g.toml").write_text('name = "g"\nlength_unit = "mm"\nhorn_length = 25\nrod_length = 160\n'
                                     "servo_angle_range = [-0.5, 1.0]\n[symmetric]\nbase_radius = 100\n"
                                     "base_pair_angle = 40\nplatform_radius = 80\nplatform_pair_angle = 16\n")  # fmt: skip
    code, _, err = cli(capfd, "ik", "0", "0", "0", "0", "0", "0", "--geometry", "g.toml", cwd=tmp_path)
    assert code == 1 and 'check angle_unit (angle_unit = "deg" for degrees)' in err, err
    code, _, err = cli(capfd, "render", "0", "0", "0", "0", "0", "0", "--out", "~/home.png", cwd=tmp_path)
    assert code == 0 and (tmp_path / "~" / "home.png").stat().st_size > 1000, err


@pytest.mark.slow
@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full (a device that is always full) here")
def test_evaluate_prints_its_figures_before_a_gif_that_cannot_be_written(tmp_path: Path,
                                                                         capfd: pytest.CaptureFixture) -> None:  # fmt: skip
    (tmp_path / "full.gif").symlink_to("/dev/full")  # passes every check; the disk is full when it is written
    code, out, err = cli(capfd, "evaluate", "--policy", "pid", "--episodes", "1", "--gif", "full.gif", "--json",
                         cwd=tmp_path)  # fmt: skip
    assert code == 1 and "no space left on device" in err
    assert json.loads(out)["policy"] == "pid"  # the episodes' figures, printed before the GIF


def test_output_the_encoding_cannot_hold_is_printed_not_raised() -> None:
    """stdout in a code page without '≈' or '−' (a Windows console's output sent to a file: cp1252): the command
    prints its figures with '?' in their place and exits 0, where it raised UnicodeEncodeError."""
    proc = subprocess.run([sys.executable, "-m", "stewart_gym", "workspace", "--n", "5"], capture_output=True,
                          env={**os.environ, "PYTHONIOENCODING": "cp1252"}, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr.decode("cp1252")
    assert b"translational workspace at home orientation ? " in proc.stdout
