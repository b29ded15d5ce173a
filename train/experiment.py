"""What the experiment scripts of ``train/`` share: the Control page's metrics, reported as one JSON line.

They import it as a sibling module (``python train/<script>.py`` puts ``train/`` first on the path).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

#: The Control page's metrics of one evaluation (``stewart_gym.evaluation.evaluate``), as every script reports them.
METRICS = ("success_rate", "rms_error_mm", "final_error_mm", "settling_time_s", "settled_pulse_rate_us_per_s",
           "settled_pulse_p2p_us")  # fmt: skip


def report(row: dict[str, Any], metrics: dict[str, Any], out: str | Path | None, digits: int | None = None) -> str:
    """``row`` (what was run) with the evaluation's :data:`METRICS` (rounded to ``digits`` if given), printed as
    one JSON line and also written to ``out`` if given; returns the line."""
    def value(v: Any) -> Any:
        return v if v is None or digits is None else round(float(v), digits)

    line = json.dumps({**row, **{k: value(metrics[k]) for k in METRICS}})
    print(line)
    if out:
        Path(out).write_text(line + "\n")
    return line
