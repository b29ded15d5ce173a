"""Write the manual's generated parts into its pages, between their markers, so that a reader of ``docs/src/``
sees the tables themselves: ``.venv/bin/python docs/generate.py`` (``--check``: write nothing, exit 1 naming
each stale page; a test runs it).

A page holds ``<!-- generated:NAME start … -->`` and ``<!-- generated:NAME end -->``; what lies between is
:data:`BLOCKS` [NAME]'s output.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

SRC = Path(__file__).resolve().parent / "src"


def _env_table() -> str:
    from stewart_gym.envs import env_table

    return env_table()


def _action_table() -> str:
    from stewart_gym.actions import action_table

    return action_table()


def _observation_table() -> str:
    from stewart_gym.sensing import observation_table

    return observation_table()


def _exit_codes() -> str:
    from stewart_gym.cli.common import exit_code_table

    return exit_code_table()


def _cli_reference() -> str:
    from stewart_gym.cli.reference import cli_reference

    return cli_reference()


def _deploy_behaviour() -> str:
    from stewart_gym.hardware.behaviour import behaviour_table

    return behaviour_table()


#: Each generated block by its marker name: the function that makes it (from the code that defines it).
BLOCKS: dict[str, Callable[[], str]] = {
    "env-table": _env_table,
    "action-table": _action_table,
    "observation-table": _observation_table,
    "exit-codes": _exit_codes,
    "cli-reference": _cli_reference,
    "deploy-behaviour": _deploy_behaviour,
}
MARKER = re.compile(r"(<!-- generated:([a-z-]+) start[^>]*-->\n)(.*?)(<!-- generated:\2 end -->)", re.DOTALL)


def render(text: str, made: dict[str, str] | None = None) -> str:
    """``text`` (a page) with every generated block made anew; an unknown block name raises ``KeyError``."""
    made = {} if made is None else made

    def fill(match: re.Match) -> str:
        name = match.group(2)
        if name not in made:
            made[name] = BLOCKS[name]().rstrip("\n") + "\n"
        return f"{match.group(1)}{made[name]}{match.group(4)}"

    return MARKER.sub(fill, text)


def stale_pages(src: Path = SRC, write: bool = False) -> list[Path]:
    """The pages whose generated blocks differ from what the code makes now (written anew with ``write``)."""
    made: dict[str, str] = {}
    stale = []
    for page in sorted(src.rglob("*.md")):
        text = page.read_text()
        fresh = render(text, made)
        if fresh != text:
            stale.append(page)
            if write:
                page.write_text(fresh)
    return stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if a page is stale")
    args = parser.parse_args(argv)
    stale = stale_pages(write=not args.check)
    for page in stale:
        print(f"{'stale' if args.check else 'wrote'}: {page.relative_to(SRC.parent.parent)}")
    return 1 if (args.check and stale) else 0


if __name__ == "__main__":
    sys.exit(main())
