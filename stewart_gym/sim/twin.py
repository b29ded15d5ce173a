"""A platform's twin: the physical parameters of one real platform, in one TOML file.

Every command that simulates a platform reads it (``--twin FILE``), and ``stewart-gym sysid`` writes it. The
file has four tables; a missing key takes its nominal value, an unknown key or a value out of its physical range
is a :class:`~stewart_gym.errors.ConfigError` naming the file and the key::

    [servos]
    speed_scale = 1.0                  # × the servo model's nominal speed
    deadband_us = 5.0
    trim_us = [0, 0, 0, 0, 0, 0]       # each servo's neutral error (what a perfect calibration would remove)
    latency_ms = 0.0                   # delay between a pulse leaving and the servo acting on it
    [ball]
    mass_scale = 1.0
    radius_scale = 1.0
    rolling_friction = 0.0             # m
    hollow = false                     # true: a thin shell, such as a ping-pong ball
    [plate]
    friction = 0.6
    load_kg = 0.0
    [sensor]
    noise_mm = 1.0
    latency_ms = 10.0

``sysid`` adds a ``[fit]`` table: the keys the logs could not determine (``undetermined``) and the one-sigma
uncertainty of each fitted value (``[fit.sigma]``, keyed ``"table.key"``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stewart_gym.errors import ConfigError

__all__ = ["FIT_KEYS", "SWITCHES", "TWIN_FIELDS", "Twin", "load_twin"]

#: Every key of a twin file: ``(table, key)`` → (nominal value, lowest, highest, unit, what it is); a key whose
#: nominal value is a bool (:data:`SWITCHES`) takes true or false.
TWIN_FIELDS: dict[tuple[str, str], tuple[Any, float, float, str, str]] = {
    ("servos", "speed_scale"): (1.0, 0.1, 5.0, "×", "the servos' speed, × the servo model's nominal no-load speed"),
    ("servos", "deadband_us"): (5.0, 0.0, 50.0, "µs", "pulse changes this small are ignored"),
    ("servos", "trim_us"): ((0.0,) * 6, -200.0, 200.0, "µs",
                            "each servo's neutral error: its physical neutral minus the calibrated one (six values)"),
    ("servos", "latency_ms"): (0.0, 0.0, 200.0, "ms",
                               "delay between a pulse leaving the computer and the servo acting on it, on top of "
                               "the servo model's own 10 ms lag"),
    ("ball", "mass_scale"): (1.0, 0.02, 10.0, "×", "the ball's mass, × the nominal 66.8 g (a 2.7 g ping-pong ball: "
                                                   "0.04)"),
    ("ball", "radius_scale"): (1.0, 0.5, 2.0, "×", "the ball's radius, × the nominal 12.7 mm (a 40 mm ping-pong ball: "
                                                   "1.575)"),
    ("ball", "rolling_friction"): (0.0, 0.0, 1e-3, "m", "rolling friction (lever arm)"),
    ("ball", "hollow"): (False, 0, 1, "", "true: the ball is a thin shell, such as a ping-pong ball (I = 2/3 m r², "
                                          "rolling at 3/5 g sin θ); false: the nominal ball's own (a solid one, "
                                          "I = 2/5 m r², 5/7 g sin θ)"),
    ("plate", "friction"): (0.6, 0.05, 2.0, "", "friction coefficient between the ball and the plate"),
    ("plate", "load_kg"): (0.0, 0.0, 2.0, "kg", "an extra mass at the plate's centre (a cable, a sensor)"),
    ("sensor", "noise_mm"): (1.0, 0.0, 20.0, "mm", "standard deviation of each reported coordinate"),
    ("sensor", "latency_ms"): (10.0, 0.0, 300.0, "ms", "age of a reading when it reaches the computer"),
}
TABLES = ("servos", "ball", "plate", "sensor")
#: The keys that are true or false rather than numbers (no uncertainty, no range)
SWITCHES = tuple(f"{t}.{k}" for (t, k), entry in TWIN_FIELDS.items() if isinstance(entry[0], bool))
#: The table ``sysid`` adds: ``sigma`` (one-sigma uncertainties, keyed ``"table.key"``) and ``undetermined``
#: (the keys the logs could not determine).
FIT_TABLE = "fit"
FIT_KEYS = ("sigma", "undetermined")


@dataclass(frozen=True)
class Twin:
    """One platform's physical parameters (see the module's description for each).

    Attributes:
        values: ``(table, key)`` → value, every key of :data:`TWIN_FIELDS`.
        sigma: ``"table.key"`` → one-sigma uncertainty of a fitted value (empty for a twin written by hand).
        undetermined: the ``"table.key"`` names the fit could not determine.
        source: the file it was read from, for messages.
        omitted: the ``"table.key"`` names the file leaves out (their values are the nominal ones): a twin of
            one's ball alone (a ``[ball]`` table) says nothing of the servos, which training then draws as it
            would without a twin.
    """

    values: dict[tuple[str, str], Any] = field(default_factory=lambda: {k: v[0] for k, v in TWIN_FIELDS.items()})
    sigma: dict[str, float] = field(default_factory=dict)
    undetermined: tuple[str, ...] = ()
    source: str = "twin"
    omitted: tuple[str, ...] = ()

    def __getitem__(self, name: str) -> Any:
        """A value by ``"table.key"``, e.g. ``twin["servos.speed_scale"]``."""
        table, _, key = name.partition(".")
        return self.values[(table, key)]

    @property
    def total_latency_ms(self) -> float:
        """Sensor plus servo latency, ms: what the ball's response to a pulse shows."""
        return float(self["servos.latency_ms"] + self["sensor.latency_ms"])

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = "twin") -> Twin:
        """A twin from the parsed tables; checks every key and value (:class:`ConfigError` naming ``source``)."""
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: a twin is a set of TOML tables, got {type(data).__name__}")
        unknown = sorted(set(data) - set(TABLES) - {FIT_TABLE})
        loose = [k for k in unknown if not isinstance(data[k], Mapping)]
        if loose:
            raise ConfigError(f"{source}: key(s) {loose} outside any table; a twin's keys go in its tables, such as "
                              "[servos] speed_scale = 0.5 (docs: Configuration files, twin)")  # fmt: skip
        if unknown:
            raise ConfigError(f"{source}: unknown table(s) {unknown}; a twin has [servos], [ball], [plate], [sensor]")
        values = {k: v[0] for k, v in TWIN_FIELDS.items()}
        for table in TABLES:
            given = data.get(table, {})
            if not isinstance(given, Mapping):
                raise ConfigError(f"{source}: [{table}] must be a table, got {given!r}")
            keys = sorted(k for (t, k) in TWIN_FIELDS if t == table)
            bad = sorted(set(given) - set(keys))
            if bad:
                raise ConfigError(f"{source}: unknown key(s) {bad} in [{table}]; its keys: {keys}")
            for key, value in given.items():
                values[(table, key)] = _checked(source, table, key, value)
        sigma, undetermined = _fit_table(source, data.get(FIT_TABLE, {}))
        omitted = tuple(f"{t}.{k}" for t, k in TWIN_FIELDS if k not in data.get(t, {}))
        return cls(values, sigma, undetermined, source, omitted)

    def to_mapping(self) -> dict[str, Any]:
        """The tables, as :meth:`from_mapping` reads them (with ``[fit]`` where there is one): the keys given, not
        those :attr:`omitted`."""
        out: dict[str, Any] = {t: {} for t in TABLES}
        for (table, key), value in self.values.items():
            if f"{table}.{key}" in self.omitted:
                continue
            out[table][key] = list(value) if isinstance(value, tuple) else value
        if self.sigma or self.undetermined:
            out[FIT_TABLE] = {"sigma": dict(self.sigma), "undetermined": list(self.undetermined)}
        return out

    def replaced(self, **changes: Any) -> Twin:
        """A copy with some values changed, keyed ``table__key`` (``servos__speed_scale=0.5``), each checked."""
        values = dict(self.values)
        for name, value in changes.items():
            table, _, key = name.partition("__")
            if (table, key) not in TWIN_FIELDS:
                raise ConfigError(f"{self.source}: no twin key {table}.{key}")
            values[(table, key)] = _checked(self.source, table, key, value)
        given = {name.replace("__", ".", 1) for name in changes}
        return Twin(values, dict(self.sigma), self.undetermined, self.source,
                    tuple(name for name in self.omitted if name not in given))  # fmt: skip

    def toml(self, comments: Mapping[str, str] | None = None) -> str:
        """The twin as a TOML file; ``comments`` (``"table.key"`` → text) go beside the values."""
        comments = comments or {}
        lines: list[str] = []
        for table in TABLES:
            lines.append(f"[{table}]")
            for (t, key), value in self.values.items():
                if t != table:
                    continue
                if isinstance(value, bool):
                    text = "true" if value else "false"
                elif isinstance(value, tuple):
                    text = "[" + ", ".join(f"{v:.1f}" for v in value) + "]"
                else:
                    text = f"{value:.6g}"
                note = comments.get(f"{table}.{key}")
                lines.append(f"{key} = {text}" + (f"  # {note}" if note else ""))
            lines.append("")
        if self.sigma or self.undetermined:
            lines.append(f"[{FIT_TABLE}]")
            lines.append("undetermined = [" + ", ".join(f'"{u}"' for u in self.undetermined) + "]")
            lines.append(f"[{FIT_TABLE}.sigma]")
            lines.extend(f'"{name}" = {value:.4g}' for name, value in self.sigma.items())
            lines.append("")
        return "\n".join(lines)


def _checked(source: str, table: str, key: str, value: Any) -> Any:
    _, lo, hi, unit, _ = TWIN_FIELDS[(table, key)]
    unit = f" {unit}" if unit and unit != "×" else ""
    if isinstance(TWIN_FIELDS[(table, key)][0], bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: {table}.{key} must be true or false, got {value!r}")
        return bool(value)
    if key == "trim_us":
        items = list(value) if isinstance(value, (list, tuple)) else None
        if items is None or len(items) != 6 or not all(_number(v) and lo <= v <= hi for v in items):
            raise ConfigError(f"{source}: servos.trim_us must be six numbers in {lo:g}…{hi:g} µs, got {value!r}")
        return tuple(float(v) for v in items)
    if not (_number(value) and lo <= value <= hi):
        raise ConfigError(f"{source}: {table}.{key} must be a number in {lo:g}…{hi:g}{unit}, got {value!r}")
    return float(value)


def _number(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def _fit_table(source: str, fit: Any) -> tuple[dict[str, float], tuple[str, ...]]:
    if not isinstance(fit, Mapping):
        raise ConfigError(f"{source}: [fit] must be a table, got {fit!r}")
    names = {f"{t}.{k}" for t, k in TWIN_FIELDS}
    bad = sorted(set(fit) - set(FIT_KEYS))
    if bad:
        raise ConfigError(f"{source}: unknown key(s) {bad} in [fit]; its keys: {list(FIT_KEYS)}")
    sigma = fit.get("sigma", {})
    undetermined = fit.get("undetermined", [])
    if not isinstance(sigma, Mapping):
        raise ConfigError(f"{source}: fit.sigma must be a table of twin keys (\"servos.speed_scale\" = 0.04, …), got "
                          f"{sigma!r}")  # fmt: skip
    for name, value in sigma.items():
        if name not in names or name in SWITCHES:
            raise ConfigError(f"{source}: fit.sigma \"{name}\": not a twin key with a number; fit.sigma maps keys such "
                              "as \"servos.speed_scale\" to their uncertainty")  # fmt: skip
        if not (_number(value) and value >= 0):
            raise ConfigError(f"{source}: fit.sigma \"{name}\" must be a number ≥ 0, got {value!r}")
    for name, value in sigma.items():  # an uncertainty wider than the value's whole range says nothing more
        _, lo, hi, unit, _ = TWIN_FIELDS[tuple(name.split("."))]
        if value > hi - lo:
            raise ConfigError(f"{source}: fit.sigma \"{name}\" = {value:g} is wider than the value's whole range "
                              f"({lo:g}…{hi:g}{'' if unit in ('', '×') else ' ' + unit})")  # fmt: skip
    if not isinstance(undetermined, list):
        raise ConfigError(f"{source}: fit.undetermined must list twin keys (\"ball.mass_scale\", …), got "
                          f"{undetermined!r}")  # fmt: skip
    unknown = [u for u in undetermined if u not in names]
    if unknown:
        raise ConfigError(f"{source}: fit.undetermined lists {unknown[0]!r}, not a twin key (such as "
                          "\"ball.mass_scale\")")  # fmt: skip
    return {k: float(v) for k, v in sigma.items()}, tuple(undetermined)


def load_twin(twin: Twin | Mapping[str, Any] | str | Path) -> Twin:
    """A :class:`Twin` from a file path, parsed tables, or a twin (returned as it is)."""
    if isinstance(twin, Twin):
        return twin
    if isinstance(twin, Mapping):
        return Twin.from_mapping(twin)
    if isinstance(twin, (str, Path)):
        from stewart_gym.tomlio import read_toml

        data = read_toml(twin, ConfigError, "twin file")
        loaded = Twin.from_mapping(data, source=str(twin)) if data else None
        if loaded is None or len(loaded.omitted) == len(TWIN_FIELDS):  # (an emptied file, a failed copy, a [fit]
            # table alone: not a nominal platform said in so many words)
            raise ConfigError(f"{twin}: the twin file sets nothing; a twin has [servos], [ball], [plate] or [sensor] "
                              "tables with values (stewart-gym sysid writes one)")  # fmt: skip
        return loaded
    raise ConfigError(f"twin must be a twin file path or its tables, got {type(twin).__name__}")
