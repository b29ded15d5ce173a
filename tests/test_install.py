"""Installing: the check `make` runs on the Python it is given before it creates .venv; the distribution (a wheel
and an sdist that ``twine check`` passes, carrying the shipped policies, the hyperparameters, the models and the
sketch); and the extras: a fresh virtual environment with the wheel's ``[deploy]`` only runs an exported bundle on
a fake device, and one with the wheel's ``[demo]`` only (what ``make demo`` installs) runs the demo.

That is what a Raspberry Pi next to the platform gets: numpy, scipy, matplotlib, onnxruntime and pyserial;
no torch, no Stable-Baselines3, no PyBullet, no Gymnasium. Slow (it builds a venv and installs into it).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import Board, FakeDevice

ROOT = Path(__file__).resolve().parents[1]


# The tests that take it share an xdist group: on `make test`'s workers it is still made once.
@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``python -m build``: the wheel and the sdist, as a release would publish them."""
    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run([sys.executable, "-m", "build", "--outdir", str(out), str(ROOT)], capture_output=True,
                          text=True, timeout=900)  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return out


@pytest.mark.xdist_group("dist")
@pytest.mark.slow
def test_the_distribution_would_publish_as_it_is(dist: Path) -> None:
    import zipfile

    wheel, sdist = next(dist.glob("*.whl")), next(dist.glob("*.tar.gz"))
    check = subprocess.run([sys.executable, "-m", "twine", "check", "--strict", str(wheel), str(sdist)],
                           capture_output=True, text=True, timeout=300)  # fmt: skip
    assert check.returncode == 0 and check.stdout.count("PASSED") == 2, check.stdout + check.stderr
    names = zipfile.ZipFile(wheel).namelist()
    for wanted in ("stewart_gym/policies/balance/bundle/policy.onnx", "stewart_gym/policies/balance/bundle/bundle.json",
                   "stewart_gym/policies/pid_gains.json", "stewart_gym/policies/lqr_pid.json",
                   "stewart_gym/hyperparams/ppo.yml", "stewart_gym/hyperparams/ppo_camera.yml",
                   "stewart_gym/presets.py"):  # fmt: skip
        assert wanted in names, wanted
    shared = [n for n in names if ".data/data/share/stewart_gym/" in n]
    assert {Path(n).name for n in shared} >= {"servo_hexapod.urdf", "servo_hexapod_plate.urdf", "servo_hexapod.xml",
                                             "stewart_pca9685.ino"}, shared  # fmt: skip


@pytest.mark.xdist_group("dist")
@pytest.mark.slow
def test_deploy_only_install_runs_a_bundle(tmp_path: Path, device: FakeDevice, dist: Path) -> None:
    bundle = tmp_path / "bundle"
    made = subprocess.run([sys.executable, "-m", "stewart_gym", "export", "--policy", "shipped", "--out", str(bundle)],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert made.returncode == 0, made.stderr
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    wheel = next(dist.glob("*.whl"))
    # (--no-compile: pip would byte-compile every module of every package; each compiles as it is imported instead)
    install = subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-compile", f"{wheel}[deploy]"],
                             capture_output=True, text=True, timeout=1200, env=env)  # fmt: skip
    assert install.returncode == 0, install.stdout[-2000:] + install.stderr[-2000:]
    heavy = "('torch', 'stable_baselines3', 'pybullet', 'gymnasium', 'yaml')"
    probe = f"import importlib.util as u; print([m for m in {heavy} if u.find_spec(m)])"
    absent = subprocess.run([str(py), "-c", probe], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert absent.returncode == 0 and absent.stdout.strip() == "[]", absent.stdout + absent.stderr

    drain = Board(device, "line", lines=lambda t: b"B 20.0,-10.0\n")  # the sketch: "ready", answers, the panel
    for policy in (str(bundle), "shipped", "pid"):
        run = subprocess.run([str(venv / "bin" / "stewart-gym"), "deploy", "--policy", policy, "--port", device.path,
                              "--protocol", "line", "--sensor", "panel", "--duration", "1", "--log",
                              str(tmp_path / f"log_{len(policy)}.csv")],
                             capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)  # fmt: skip
        assert run.returncode == 0, run.stdout + run.stderr
        assert "completed" in run.stdout and "servos homed: confirmed by the board" in run.stdout
    data = drain.stop()
    assert data.count(b"W ") >= 150
    # the simulated sensor needs the [sim] extra, and says so in one line
    sim = subprocess.run([str(venv / "bin" / "stewart-gym"), "deploy", "--port", device.path, "--protocol", "line",
                          "--sensor", "sim", "--duration", "1"], capture_output=True, text=True, cwd=tmp_path, env=env,
                         timeout=120)  # fmt: skip
    assert sim.returncode == 1 and "stewart_gym[sim]" in sim.stderr and "Traceback" not in sim.stderr


def load_check_python():
    import importlib.util

    spec = importlib.util.spec_from_file_location("check_python", ROOT / ".ci" / "check_python.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_make_checks_the_python_before_it_creates_the_venv(tmp_path: Path) -> None:
    """`make demo` and `make test` first run `.ci/check_python.py` with the Python given to make (PYTHON=…): on
    this machine's Python it says nothing and exits 0."""
    outer = ("MAKEFLAGS", "MAKELEVEL", "MFLAGS")  # set when the suite itself runs under `make test`
    dry = subprocess.run(["make", "--no-print-directory", "-n", "-B", f"VENV={tmp_path / 'venv'}",
                          "PYTHON=python3.11", str(tmp_path / "venv" / ".installed")], capture_output=True, text=True,
                         cwd=ROOT, timeout=60, env={k: v for k, v in os.environ.items() if k not in outer})  # fmt: skip
    assert dry.returncode == 0, dry.stderr
    assert dry.stdout.splitlines()[0] == "python3.11 .ci/check_python.py", dry.stdout
    assert '-e ".[dev]"' in dry.stdout.splitlines()[-2], dry.stdout
    demo = subprocess.run(["make", "--no-print-directory", "-n", "-B", f"VENV={tmp_path / 'venv'}",
                           "PYTHON=python3.11", str(tmp_path / "venv" / ".installed-demo")], capture_output=True,
                          text=True, cwd=ROOT, timeout=60,
                          env={k: v for k, v in os.environ.items() if k not in outer})  # fmt: skip
    assert demo.returncode == 0, demo.stderr
    assert demo.stdout.splitlines()[0] == "python3.11 .ci/check_python.py --demo", demo.stdout
    assert '-e ".[demo]"' in demo.stdout.splitlines()[-2], demo.stdout
    ran = subprocess.run([sys.executable, str(ROOT / ".ci" / "check_python.py")], capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert (ran.returncode, ran.stdout, ran.stderr) == (0, "", ""), ran.stderr


@pytest.mark.parametrize(("version", "system", "machine", "headers", "compiler", "says", "demo"), [
    ((3, 9), "Linux", "x86_64", True, True, "needs Python 3.10 or newer, and this is Python 3.9", False),
    ((3, 10), "Linux", "x86_64", False, False, None, False),  # PyBullet's wheel: nothing to compile
    ((3, 11), "Linux", "x86_64", False, False, None, False),
    ((3, 12), "Linux", "x86_64", True, True, None, False),  # compiles, and can
    ((3, 12), "Linux", "x86_64", False, True, "lacks the Python headers: install them (Debian/Ubuntu: sudo apt "
                                              "install g++ python3.12-dev), or run make with PYTHON=python3.11",
     False),
    ((3, 13), "Linux", "x86_64", True, False, "lacks a C++ compiler", False),
    ((3, 12), "Linux", "x86_64", False, False, "lacks the Python headers and a C++ compiler", False),
    ((3, 11), "Linux", "aarch64", False, True, "no wheel for Python 3.11 on Linux aarch64", False),
    ((3, 11), "Darwin", "arm64", True, True, None, False),
    ((3, 13), "Linux", "x86_64", False, False, "; make demo needs neither (it runs on MuJoCo here)", False),
    ((3, 13), "Linux", "x86_64", False, False, None, True),  # make demo: MuJoCo, nothing to compile
    ((3, 9), "Linux", "x86_64", True, True, "needs Python 3.10 or newer", True),
    ((3, 11), "Linux", "aarch64", False, True, "lacks the Python headers: install", True),  # PyBullet there still
])  # fmt: skip
def test_the_python_check_names_what_is_missing(version, system, machine, headers, compiler, says, demo) -> None:
    message = load_check_python().problem(version, system, machine, headers, compiler, demo)
    if says is None:
        assert message is None
    else:
        assert message.startswith("error: ") and says in message and "\n" not in message, message


@pytest.mark.xdist_group("dist")
@pytest.mark.slow
def test_demo_only_install_runs_the_demo_without_torch(tmp_path: Path, dist: Path) -> None:
    """What ``make demo`` installs (the wheel's ``[demo]``) into a fresh venv: no torch, Stable-Baselines3 or Ray;
    ``stewart-gym demo`` runs there, the shipped networks as their ONNX bundles; and the envs pass Gymnasium's
    own checks on the Gymnasium that pip picks there (the dev extra's RLlib pins an older one)."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    wheel = next(dist.glob("*.whl"))
    install = subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-compile", "-c", str(ROOT / "constraints.txt"),
                              f"{wheel}[demo]"], capture_output=True, text=True, timeout=1200, env=env)  # fmt: skip
    assert install.returncode == 0, install.stdout[-2000:] + install.stderr[-2000:]
    probe = ("import importlib.util as u; print([m for m in ('torch', 'stable_baselines3', 'ray', 'cv2', 'pytest') "
             "if u.find_spec(m)])")  # fmt: skip
    absent = subprocess.run([str(py), "-c", probe], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert absent.returncode == 0 and absent.stdout.strip() == "[]", absent.stdout + absent.stderr

    demo = subprocess.run([str(venv / "bin" / "stewart-gym"), "demo", "--episodes", "2", "--out", "out"],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)  # fmt: skip
    assert demo.returncode == 0 and "Traceback" not in demo.stderr, demo.stdout[-2000:] + demo.stderr[-2000:]
    # said once, although the policies are evaluated in worker processes
    assert demo.stderr.count("run as their ONNX bundles") == 1, demo.stderr
    metrics = json.loads((tmp_path / "out" / "demo_metrics.json").read_text())
    assert list(metrics) == ["shipped-residual", "shipped", "pid-kalman", "lqr"]
    assert all(m["success_rate"] == 1.0 for m in metrics.values()), metrics
    assert (tmp_path / "out" / "demo.gif").stat().st_size > 10_000 and (tmp_path / "out" / "demo_pulses.png").exists()

    check = ("import gymnasium as gym, stewart_gym\n"
             "from gymnasium.utils.env_checker import check_env\n"
             "for env_id in ('StewartBallBalance-v0', 'StewartBallTrack-v0', 'StewartBallDisturbance-v0'):\n"
             "    env = gym.make(env_id, render_mode='rgb_array')\n"
             "    check_env(env.unwrapped)\n"
             "    env.close()\n"
             "print(gym.__version__)\n")  # fmt: skip
    checked = subprocess.run([str(py), "-c", check], capture_output=True, text=True, cwd=tmp_path, env=env,
                             timeout=600)  # fmt: skip
    assert checked.returncode == 0, checked.stderr[-3000:]
