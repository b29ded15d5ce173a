"""Size and time of an install into a fresh venv, per extra: what `make demo` (the ``demo`` extra) and `make test`
(``dev``) install (docs: Getting started). Packages come from pip's index and cache as they would for a user.

Run: ``.venv/bin/python bench/bench_install.py [--extras demo,dev]``. Prints one line per extra: the venv's size
and the wall time of ``pip install -c constraints.txt -e ".[EXTRA]"`` (the venv and pip's upgrade not counted).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def folder_size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--extras", default="demo,dev", help="comma-separated extras, each in its own venv")
    args = parser.parse_args()
    for extra in args.extras.split(","):
        with tempfile.TemporaryDirectory() as folder:
            venv = Path(folder) / "venv"
            subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
            pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q"]
            subprocess.run([*pip, "--upgrade", "pip"], check=True, capture_output=True)
            start = time.perf_counter()
            proc = subprocess.run([*pip, "-c", str(ROOT / "constraints.txt"), "-e", f"{ROOT}[{extra}]"],
                                  capture_output=True, text=True)  # fmt: skip
            wall = time.perf_counter() - start
            if proc.returncode != 0:
                sys.exit(f"error: installing [{extra}] failed:\n{proc.stderr[-2000:]}")
            print(f"[{extra}]  {folder_size(venv) / 1e9:5.2f} GB  {wall:6.1f} s")


if __name__ == "__main__":
    main()
