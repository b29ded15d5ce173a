"""The ``stewart-gym`` command line.

Every subcommand checks its arguments before it starts work, prints a user's
mistake as one ``error: …`` line and exits with a code that means something
(see :mod:`stewart_gym.cli.common`): 0 done, 1 user error or failed result, 2
device failure. ``--debug`` shows tracebacks. Each group of commands lives in
its own module and adds itself to the parser with ``register(sub)``:
:mod:`~stewart_gym.cli.kinematics`, :mod:`~stewart_gym.cli.learning`,
:mod:`~stewart_gym.cli.hardware` and :mod:`~stewart_gym.cli.analysis`.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence

from stewart_gym import AS_COMMAND, NOTED_WHILE_LOADING, SIGNALS_WHILE_LOADING, note_stops_while_loading

note_stops_while_loading()  # a stop while the modules below load is noted too, until main() installs its handlers

from stewart_gym.cli.common import (  # noqa: E402
    EXIT_CODES_HELP,
    Parser,
    geometry_text,
    interrupted,
    run,
    stop_behind,
    stop_signals,
)

__all__ = ["build_parser", "main"]


def _version() -> str:
    from stewart_gym import __version__

    return __version__


def build_parser() -> argparse.ArgumentParser:
    # imported here: main() handles Ctrl-C meanwhile
    from stewart_gym.cli import analysis, hardware, identification, kinematics, learning

    parser = Parser(prog="stewart-gym", description="Servo Stewart platform toolkit", epilog=EXIT_CODES_HELP)
    parser.add_argument("--version", action="version", version=f"stewart-gym {_version()}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of any error")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for group in (kinematics, learning, hardware, identification, analysis):
        group.register(sub)
    for sp in sub.choices.values():  # --debug is accepted after the subcommand too
        sp.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show the traceback of any error")
        for action in sp.arguments():  # every --geometry: not empty (an empty path is the current folder)
            if action.dest == "geometry":
                action.type = geometry_text
    parser.set_defaults(subcommand_parsers=sub.choices)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; its exit code. A stop signal at any moment (Ctrl-C, SIGTERM, SIGHUP), while the parser and
    the commands' modules load too, is one ``error:`` line and exit code 128 + its number. In the command's own
    process a Ctrl-C after the command has done its work and said so is ignored: it would only cut Python's
    teardown short (with a traceback of a library's exit handler, or a silent exit 130)."""
    readable_everywhere(sys.stdout)
    code = _main(argv)
    _done()  # (again: leaving stop_signals() put its handler back)
    return code


def readable_everywhere(stream: object) -> None:
    """Let ``stream`` print what its encoding cannot hold (µ, −, ° in a table) as ``?`` instead of raising: a
    Windows console's output sent to a file or a pipe is in the ANSI code page (cp1252), which has no minus
    sign."""
    reconfigure = getattr(stream, "reconfigure", None)
    encoding = str(getattr(stream, "encoding", "") or "").lower().replace("-", "").replace("_", "")
    if reconfigure is not None and encoding not in ("utf8", "utf8sig"):
        try:
            reconfigure(errors="replace")
        except (ValueError, OSError):  # a closed or detached stream: nothing to print to
            pass


def _done() -> None:
    if AS_COMMAND and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _main(argv: Sequence[str] | None) -> int:
    debug = "--debug" in (sys.argv[1:] if argv is None else argv)
    while NOTED_WHILE_LOADING:  # back to the default, which stop_signals() restores after the command
        signal.signal(*NOTED_WHILE_LOADING.pop())
    with stop_signals():
        try:
            if SIGNALS_WHILE_LOADING:  # a stop that came while the modules loaded
                signum = SIGNALS_WHILE_LOADING[0]
                SIGNALS_WHILE_LOADING.clear()
                if signum == signal.SIGINT:
                    raise KeyboardInterrupt
                from stewart_gym.errors import Stopped

                raise Stopped(signum, signal.Signals(signum).name)
            args, unknown = build_parser().parse_known_args(argv)
            if unknown:  # named by the subcommand that was given them, which lists what it takes
                args.subcommand_parsers[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
            code = run(args.func, args)
            _done()
            return code
        except KeyboardInterrupt as exc:
            if debug:
                raise
            return interrupted(exc)
        except ImportError as exc:  # a stop inside a C extension's import (scipy's, while the parser loads)
            stop = stop_behind(exc)
            if stop is None or debug:
                raise
            return interrupted(stop)


if __name__ == "__main__":
    sys.exit(main())
