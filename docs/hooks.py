"""MkDocs hook: tables generated from the code, so the manual never holds a second copy.

A page writes ``{{ env_table }}``, ``{{ observation_table }}``, ``{{ action_table }}`` or
``{{ exit_codes }}`` and gets the table the code defines.
"""

from __future__ import annotations

from typing import Any


def on_page_markdown(markdown: str, **_: Any) -> str:
    if "{{" not in markdown:
        return markdown
    from stewart_gym.actions import action_table
    from stewart_gym.cli.common import exit_code_table
    from stewart_gym.envs import env_table
    from stewart_gym.sensing import observation_table

    for name, make in (("env_table", env_table), ("observation_table", observation_table),
                       ("action_table", action_table), ("exit_codes", exit_code_table)):  # fmt: skip
        markdown = markdown.replace("{{ " + name + " }}", make())
    return markdown
