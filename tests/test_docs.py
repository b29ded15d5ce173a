"""The manual's generated parts: written into the pages (no template placeholders in ``docs/src/``), equal to what
the code makes now (``docs/generate.py --check``), and a command-line reference with every subcommand and option."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

from stewart_gym.cli import build_parser

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
