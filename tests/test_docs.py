"""The manual's generated parts: written into the pages (no template placeholders in ``docs/src/``), equal to what
the code makes now (``docs/generate.py --check``), and a command-line reference with every subcommand and option."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

from stewart_gym.cli import build_parser
from stewart_gym.tomlio import tomllib

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "docs" / "src"


def generate_module():
    spec = importlib.util.spec_from_file_location("docs_generate", ROOT / "docs" / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_generated_block_is_what_the_code_makes_now() -> None:
    generate = generate_module()
    assert generate.stale_pages(SRC) == [], "run .venv/bin/python docs/generate.py"
    used = {m.group(2) for page in SRC.rglob("*.md") for m in generate.MARKER.finditer(page.read_text())}
    assert used == set(generate.BLOCKS), used ^ set(generate.BLOCKS)


def test_a_stale_block_is_found_and_rewritten(tmp_path: Path) -> None:
    generate = generate_module()
    page = tmp_path / "page.md"
    page.write_text("# A page\n\n<!-- generated:exit-codes start -->\n| old |\n<!-- generated:exit-codes end -->\n")
    assert generate.stale_pages(tmp_path) == [page] and "| old |" in page.read_text()
    assert generate.stale_pages(tmp_path, write=True) == [page]
    assert "| old |" not in page.read_text() and "| 130 |" in page.read_text()
    assert generate.stale_pages(tmp_path) == []


def test_no_page_shows_a_template_placeholder() -> None:
    hits = [f"{p.relative_to(ROOT)}:{n}" for p in SRC.rglob("*.md") for n, line in enumerate(p.read_text().splitlines(), 1)
            if re.search(r"\{\{.*\}\}", line)]  # fmt: skip
    assert not hits, hits


@pytest.mark.parametrize("command", sorted(build_parser().subcommands()))
def test_the_reference_documents_every_option_of(command: str) -> None:
    """docs/src/cli.md has a section per subcommand, with a row per argument (and a meaning in each row)."""
    page = (SRC / "cli.md").read_text()
    section = page.split(f"### `stewart-gym {command}`\n", 1)[1].split("\n### ", 1)[0]
    parser = build_parser().subcommands()[command]
    for action in parser.arguments():
        if action.dest in ("help", "debug"):
            continue
        name = action.option_strings[0] if action.option_strings else None
        rows = [row for row in section.splitlines() if row.startswith("| `") and
                (name is None or re.match(rf"\| `{re.escape(name)}[ ,`]", row))]  # fmt: skip
        assert rows, (command, action.option_strings or action.dest)
        assert all(row.rstrip().split("|")[-2].strip() for row in rows), (command, rows)


def test_the_hardware_pages_calibration_example_is_what_calibrate_writes(tmp_path: Path) -> None:
    """The example on the Hardware page has the keys ``calibrate`` writes, in its order, and loads (its one
    servo table repeated for the six)."""
    from stewart_gym.calibration import ServoCalibration
    from stewart_gym.hardware.trim import calibration_toml
    from stewart_gym.tomlio import tomllib  # tomli on Python 3.10

    page = (SRC / "hardware.md").read_text()
    block = page.split("**Calibration file** (TOML)", 1)[1].split("```toml\n", 1)[1].split("```", 1)[0]
    written = calibration_toml(ServoCalibration.default("servo-hexapod"), {"port": "/dev/ttyACM0",
                               "protocol": "maestro", "baudrate": 115200}, geometry="servo-hexapod")  # fmt: skip

    def keys(text: str) -> list[str]:
        return [line.split("=")[0].strip() for line in text.splitlines() if "=" in line and not line.startswith("#")]

    servo = block[block.index("[[servo]]"):block.index("# … five more")]
    assert keys(block) == keys(written[: written.index("[[servo]]")]) + keys(servo) + ["baudrate", "port", "protocol"]
    assert keys(servo) == keys(written[written.index("[[servo]]"):].split("\n\n")[0])
    six = block.replace(servo, "".join(servo.replace("channel = 0", f"channel = {i}") for i in range(6)))
    calibration = ServoCalibration.from_dict(tomllib.loads(six), "servo-hexapod")
    assert calibration.neutral_us[0] == 1512.0 and calibration.min_us[0] == 1112.0


def config_sections() -> dict[str, str]:
    """docs/src/config-files.md by section anchor (``## Title {#anchor}``)."""
    parts = re.split(r"^## .*\{#([a-z-]+)\}\n", (SRC / "config-files.md").read_text(), flags=re.M)
    return dict(zip(parts[1::2], parts[2::2]))


def documented_keys(section: str) -> set[str]:
    """The keys named in the first cell of a table row: ``| `a`, `b` | …``."""
    return {key for row in section.splitlines() if row.startswith("| `")
            for key in re.findall(r"`([^`]+)`", row.split("|")[1])}  # fmt: skip


def format_keys() -> dict[str, set[str]]:
    """Every key each reader of a configuration file knows, from the code (and, for bundles, what export writes)."""
    import json
    from dataclasses import fields

    from stewart_gym import calibration, geometry, sb3_models, sweep, training, vision
    from stewart_gym.control import LQRDesign, PIDGains
    from stewart_gym.control.gains import ESTIMATOR_FIELD
    from stewart_gym.control.handover import HANDOVER_SIZES
    from stewart_gym.hardware.deploy import log_columns
    from stewart_gym.hardware.export import classical_meta
    from stewart_gym.sim.twin import FIT_KEYS, TWIN_FIELDS

    bundles = [json.loads(p.read_text()) for p in (ROOT / "stewart_gym" / "policies").glob("*/bundle/bundle.json")]
    bundles.append(classical_meta("pid", {"kp": 1.0}))
    internal = {"eval_freq", "eval_episodes", "residual"}  # a recipe gives them in `evaluation:` and `env_wrapper`
    return {
        "geometry": set(geometry.GEOMETRY_FIELDS) | set(geometry.SYMMETRIC_FIELDS),
        "calibration": set(calibration.ROTARY_FIELDS + calibration.ROTARY_SERVO_FIELDS + calibration.LINEAR_FIELDS
                           + calibration.LINEAR_SERVO_FIELDS + calibration.HARDWARE_FIELDS),
        "camera": {f"{table}.{key}" for table, keys in vision.CAMERA_CONFIG_FIELDS.items() for key in keys},
        "sweep": set(sweep.SPEC_KEYS),
        "hyperparameters": (set(training.RUN_KEYS) - internal | {"env_wrapper"} | set(sb3_models.RESIDUAL_FIELDS)),
        "bundle": {key for meta in bundles for key in meta},
        "gains": ({f.name for cls in (PIDGains, LQRDesign) for f in fields(cls)} | set(HANDOVER_SIZES)
                  | {"lqr", "pid", ESTIMATOR_FIELD}),
        "twin": {f"{table}.{key}" for table, key in TWIN_FIELDS} | {f"fit.{key}" for key in FIT_KEYS},
        # numbered columns by their first (and, for the pulses, last) name
        "deploy-log": {c for c in log_columns(12, 2, plate=True) if not re.fullmatch(r"(obs|action|pulse)\d+(_us)?", c)}
                      | {"obs0", "action0", "pulse0_us", "pulse5_us"},
    }


@pytest.mark.parametrize("name", sorted(format_keys()))
def test_the_config_reference_documents_every_key_of(name: str) -> None:
    """Each format's section has a row for every key its reader accepts (or, for a bundle, export writes)."""
    missing = format_keys()[name] - documented_keys(config_sections()[name])
    assert not missing, f"config-files.md#{name} does not document {sorted(missing)}"


def test_the_config_references_examples_load(tmp_path: Path) -> None:
    """The example file of each format user writes is one its reader accepts."""
    from stewart_gym.calibration import ServoCalibration
    from stewart_gym.geometry import PlatformGeometry
    from stewart_gym.sweep import load_sweep
    from stewart_gym.training import load_hyperparams
    from stewart_gym.vision import CameraConfig

    sections = config_sections()

    def example(name: str, suffix: str) -> Path:
        block = re.search(r"```(?:toml|yaml|json)\n(.*?)```", sections[name], flags=re.S).group(1)
        path = tmp_path / f"{name}{suffix}"
        path.write_text(block)
        return path

    geo = PlatformGeometry.from_toml(example("geometry", ".toml"))
    assert geo.name == "my-platform" and geo.is_rotary
    text = example("calibration", ".toml").read_text().replace("# … five more [[servo]] tables", "")
    servo = text[text.index("[[servo]]"):]
    others = "".join("\n" + servo.replace("channel = 0", f"channel = {i}") for i in range(1, 6))
    cal = ServoCalibration.from_dict(tomllib.loads(text + others))
    assert cal.neutral_us[0] == pytest.approx(1512.0)
    camera = CameraConfig.from_toml(example("camera", ".toml"))
    assert camera.markers.size_mm == 36
    spec = load_sweep(example("sweep", ".yml"))
    assert spec.search["learning_rate"][0] == "loguniform"
    from stewart_gym.sim.twin import Twin, load_twin

    assert load_twin(example("twin", ".toml")).values == Twin().values
    hp = load_hyperparams("ppo", "StewartBallBalance-v0", str(example("hyperparameters", ".yml")))
    assert hp["residual"]["base"] == "lqr-pid" and hp["eval_freq"] == 25000
    from stewart_gym.registry import load_classical

    pid = load_classical("pid", example("gains", ".json"))
    assert (pid.gains.kp_pos, pid.gains.ki_vel, pid.gains.feed_lead) == (2.0, 3.0, 0.06)
