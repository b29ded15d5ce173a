"""Deploy a policy as on real hardware, to a virtual servo board with the simulated platform behind it: the
board (``stewart-gym virtual-device``) runs in its own process on a pseudo-terminal, answers the serial protocol
and reports the ball as the board's touch panel would; ``deploy`` drives it at 50 Hz, homes the servos at the
end and reports whether the board confirmed it. No hardware needed.

    python examples/deploy_virtual_board.py --policy shipped-residual --duration 10
"""

from __future__ import annotations

import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from stewart_gym.cli import main as stewart_gym
from stewart_gym.cli.common import Parser, positive_float
from stewart_gym.errors import ConfigError
from stewart_gym.outputs import output_file


def main(argv: list[str] | None = None) -> int:
    parser = Parser.for_script(__doc__)
    parser.add_argument("--policy", default="shipped", help="a shipped name, a bundle or a run folder")
    parser.add_argument("--duration", type=positive_float, default=10.0, help="seconds")
    parser.add_argument("--log", help="the run's log, a row per tick (default: a new out/deploy_log_<date>-<time>.csv)")
    parser.add_argument("--overwrite", action="store_true", help="allow --log to replace an existing file")
    args = parser.parse_args(argv)
    log = ["--log", args.log] if args.log else []
    if args.log:  # checked before the board starts (deploy checks it again)
        try:
            output_file(args.log, suffixes=(".csv",), overwrite=args.overwrite)
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1

    with tempfile.TemporaryDirectory() as folder:
        port = Path(folder) / "board"
        command = [sys.executable, "-m", "stewart_gym", "virtual-device", "--protocol", "line", "--link", str(port)]
        board = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + 120
            while not port.exists():  # the board is up once its port is
                if board.poll() is not None or time.monotonic() > deadline:
                    print(board.stdout.read() if board.stdout else "", file=sys.stderr)
                    return 1
                time.sleep(0.1)
            code = stewart_gym(["deploy", "--policy", args.policy, "--port", str(port), "--protocol", "line",
                                "--sensor", "panel", "--duration", str(args.duration), *log,
                                *(["--overwrite"] if args.overwrite else [])])  # fmt: skip
        finally:
            board.send_signal(signal.SIGINT)  # the board prints what it received, then exits
            out, _ = board.communicate(timeout=60)
        print("virtual board:", out.strip().splitlines()[-1] if out.strip() else "(no summary)")
    return code


if __name__ == "__main__":
    sys.exit(main())
