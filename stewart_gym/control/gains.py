"""Gain files and bundles: reading a design's fields checked, telling its kind, and building the controller.

The shipped classical controllers by name are :data:`CLASSICAL`. A gains or design file (JSON) is a PID's
gains, an LQR's design or a hand-over's, told apart by its fields (:func:`design_kind`) and checked
(:func:`checked_design`); :func:`classical_controller` designs the controller for a build, and
:func:`controller_from_gains` rebuilds one from the gains a bundle stores.
"""

from __future__ import annotations

import json
import math
from dataclasses import fields as dataclass_fields
from pathlib import Path
from typing import Any

from stewart_gym.control.design import gains_for_geometry
from stewart_gym.control.handover import (
    HANDOVER_OPTIONAL,
    HANDOVER_SIZES,
    HandoverController,
    HandoverDesign,
    HandoverGains,
)
from stewart_gym.control.lqr import LQRController, LQRDesign, LQRGains, design_lqr
from stewart_gym.control.pid import CascadedPID, PIDGains
from stewart_gym.presets import load_geometry
from stewart_gym.sensing import ESTIMATORS

__all__ = ["CLASSICAL", "CLASSICAL_KINDS", "ESTIMATOR_FIELD", "checked_design", "checked_handover",
           "classical_controller", "controller_from_gains", "design_estimator", "design_kind", "shipped_design"]

#: The shipped classical controllers by name (``--policy NAME``, a residual policy's ``base``): their kind
#: ("pid", "lqr" or "handover"), their file under ``stewart_gym/policies/`` and the observer they run behind.
CLASSICAL = {"pid": ("pid", "pid_gains.json", "lowpass"), "pid-kalman": ("pid", "pid_kalman_gains.json", "kalman"),
             "lqr": ("lqr", "lqr.json", "kalman"), "lqr-pid": ("handover", "lqr_pid.json", "kalman")}  # fmt: skip
CLASSICAL_KINDS = ("pid", "lqr", "handover")


#: Design fields that are bounds, zones, dither or the feed-forward's lead (0 turns them off; a negative one is
#: refused) and the LQR design's acceptable sizes and servo lag (must be positive).
NON_NEGATIVE_GAINS = ("integral_limit", "integral_zone", "integral_zone_mm", "dither", "feed_lead")
POSITIVE_GAINS = ("position_mm", "velocity_mm_s", "integral_mm_s", "tilt", "tilt_step", "tilt_lag_s", "kp_pos", "kp_vel",
                  "max_tilt")  # fmt: skip
#: The PID's gains a gains file must give (the other fields have defaults: :class:`PIDGains`).
PID_REQUIRED = ("kp_pos", "kp_vel", "ki_vel")
#: The largest loop gain a PID gains file may give (1/s or 1/s²): far above any that balances a ball, low enough that
#: the loop's arithmetic stays finite.
MAX_LOOP_GAIN = 1e4
#: The LQR's acceptable sizes (Bryson's rule) and its servo lag, each within this range (in its own unit): beyond
#: it the design's weights leave what its Riccati solve can hold.
LQR_SIZES = ("position_mm", "velocity_mm_s", "integral_mm_s", "tilt_step", "tilt_lag_s")
LQR_SIZE_RANGE = (1e-6, 1e6)
#: s: the longest lead of the feed-forward (a target's acceleration a second ahead is already another target's).
MAX_FEED_LEAD_S = 1.0


#: The optional field of a gains or design file that names the observer it was tuned behind (``lowpass`` or
#: ``kalman``): a copy of ``pid_kalman_gains.json`` runs behind the Kalman observer, as ``--policy pid-kalman`` does.
ESTIMATOR_FIELD = "estimator"


def design_estimator(values: Any) -> str | None:
    """The observer a gains or design file's values name (their ``estimator`` field; None without one). Raises
    ``ValueError`` if it is not one of :data:`~stewart_gym.sensing.ESTIMATORS`."""
    if not isinstance(values, dict) or ESTIMATOR_FIELD not in values:
        return None
    named = values[ESTIMATOR_FIELD]
    if named not in ESTIMATORS:
        raise ValueError(f"{ESTIMATOR_FIELD} must be one of {list(ESTIMATORS)}, got {named!r}")
    return str(named)


def design_kind(values: Any) -> str:
    """The kind of controller a gains or design file's values describe: ``"handover"`` (``lqr`` and ``pid``
    sections), ``"lqr"`` (an LQR design: it has the acceptable sizes, e.g. ``position_mm``) or ``"pid"``."""
    if isinstance(values, dict) and {"lqr", "pid"} & set(values):
        return "handover"
    only_lqr = {f.name for f in dataclass_fields(LQRDesign)} - {f.name for f in dataclass_fields(PIDGains)}
    if isinstance(values, dict) and only_lqr & set(values):
        return "lqr"
    return "pid"


def checked_design(values: Any, kind: str) -> PIDGains | LQRDesign | HandoverDesign:
    """The PID's gains (``kind`` "pid"), the LQR's design (``"lqr"``) or the hand-over's (``"handover"``:
    :func:`checked_handover`) from a mapping of its fields, checked: known fields, finite numbers, no negative
    bound or zone, positive LQR sizes; an ``estimator`` field (:func:`design_estimator`) is checked and left
    out. Raises ``ValueError`` saying what is wrong (callers add where the values came from)."""
    if design_estimator(values) is not None:
        values = {k: v for k, v in values.items() if k != ESTIMATOR_FIELD}
    if kind == "handover":
        return checked_handover(values)
    cls = LQRDesign if kind == "lqr" else PIDGains
    if not isinstance(values, dict):
        raise ValueError(f"expected {cls.__name__} values as a mapping, got {type(values).__name__}")
    names = [f.name for f in dataclass_fields(cls)]
    unknown = sorted(set(values) - set(names))
    if unknown:
        what = "an LQR's design has" if cls is LQRDesign else "a PID's gains are"
        raise ValueError(f"unknown field(s) {unknown}: {what} {', '.join(names)} (and {ESTIMATOR_FIELD})")
    design = cls(**values)
    fields = vars(design)
    bad = [k for k, v in fields.items() if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)]
    if bad:
        raise ValueError(f"gains must be finite numbers: {bad}")
    if cls is PIDGains:
        missing = [k for k in PID_REQUIRED if k not in values]
        if missing:
            raise ValueError(f"a PID's gains need {', '.join(PID_REQUIRED)}; missing: {', '.join(missing)}")
    wrong = [f"{k} must be 0 (off) or more" for k in NON_NEGATIVE_GAINS if k in fields and fields[k] < 0]
    wrong += [f"{k} must be positive" for k in POSITIVE_GAINS if k in fields and fields[k] <= 0]
    if cls is PIDGains:
        wrong += [f"{k} must be from 0 to {MAX_LOOP_GAIN:g}, got {fields[k]}" for k in PID_REQUIRED
                  if not 0 <= fields[k] <= MAX_LOOP_GAIN and f"{k} must be positive" not in wrong]  # fmt: skip
        if fields["max_tilt"] >= math.pi / 2:
            wrong.append(f"max_tilt must be below π/2 rad (90°), got {fields['max_tilt']}")
    if not 0 < fields["rolling_factor"] <= 1:
        wrong.append(f"rolling_factor must be above 0 and at most 1 (5/7 for a solid ball), got {fields['rolling_factor']}")
    if cls is LQRDesign and fields["tilt"] > 1:
        wrong.append(f"tilt (an acceptable sin(tilt)) must be at most 1, got {fields['tilt']}")
    low, high = LQR_SIZE_RANGE
    wrong += [f"{k} must be from {low:g} to {high:g}, got {fields[k]}" for k in LQR_SIZES
              if k in fields and fields[k] > 0 and not low <= fields[k] <= high]  # fmt: skip
    if fields.get("feed_lead", 0.0) > MAX_FEED_LEAD_S:
        wrong.append(f"feed_lead must be from 0 to {MAX_FEED_LEAD_S:g} s, got {fields['feed_lead']}")
    if wrong:
        raise ValueError("; ".join(wrong))
    return design


def checked_handover(values: Any) -> HandoverDesign:
    """:class:`HandoverDesign` from a mapping (``lqr`` and ``pid`` sub-mappings and the hand-over sizes), checked."""
    if not isinstance(values, dict):
        raise ValueError(f"expected a hand-over design as a mapping, got {type(values).__name__}")
    missing = [k for k in ("lqr", "pid") if k not in values]
    unknown = sorted(set(values) - set(HANDOVER_SIZES) - {"lqr", "pid"})
    if missing or unknown:
        said = ([f"missing {', '.join(missing)}"] if missing else []) + ([f"unknown field(s) {unknown}"] if unknown else [])
        raise ValueError(f"a hand-over design: {'; '.join(said)} (its fields: lqr {{…}}, pid {{…}}, "
                         f"{', '.join(HANDOVER_SIZES)})")  # fmt: skip
    try:
        lqr, pid = checked_design(values["lqr"], "lqr"), checked_design(values["pid"], "pid")
    except ValueError as exc:
        raise ValueError(f"handover: {exc}") from None
    assert isinstance(lqr, LQRDesign) and isinstance(pid, PIDGains)
    sizes = {k: values.get(k, getattr(HandoverDesign, k)) for k in HANDOVER_SIZES}
    bad = [k for k, v in sizes.items() if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
           or v < 0 or (v == 0 and k not in HANDOVER_OPTIONAL)]  # fmt: skip
    if bad:
        raise ValueError(f"{bad} must be positive numbers ({', '.join(HANDOVER_OPTIONAL)} may be 0: off)")
    if sizes["release_mm"] <= sizes["handover_mm"]:
        raise ValueError(f"release_mm ({sizes['release_mm']}) must be more than handover_mm ({sizes['handover_mm']})")
    if sizes["push_release_mm"] >= sizes["release_mm"]:
        raise ValueError(f"push_release_mm ({sizes['push_release_mm']}) must be less than release_mm "
                         f"({sizes['release_mm']}), or 0 (off)")  # fmt: skip
    return HandoverDesign(lqr=lqr, pid=pid, **{k: float(v) for k, v in sizes.items()})


def shipped_design(name: str) -> PIDGains | LQRDesign | HandoverDesign:
    """The design of the shipped classical controller ``name`` (a key of :data:`CLASSICAL`), from its file."""
    kind, filename, _ = CLASSICAL[name]
    path = Path(__file__).resolve().parents[1] / "policies" / filename
    return checked_design(json.loads(path.read_text(encoding="utf-8")), kind)


def classical_controller(kind: str, design: PIDGains | LQRDesign | HandoverDesign, geometry: Any = "servo-hexapod",
                         dt: float = 0.02, plate_half: tuple[float, float] | None = None) -> Any:  # fmt: skip
    """The PID (``kind`` ``"pid"``, from its gains, adapted by :func:`gains_for_geometry`), the LQR (``"lqr"``,
    designed by :func:`design_lqr`) or the LQR → PID hand-over (``"handover"``, both so) for ``geometry`` at
    control period ``dt``; observation scales follow the plate (``plate_half``, default the geometry's)."""
    geo = load_geometry(geometry)
    half = plate_half or (geo.plate_extent[0] / 2, geo.plate_extent[1] / 2)
    if kind == "handover":
        assert isinstance(design, HandoverDesign)
        lqr = design_lqr(design.lqr, dt=dt, geometry=geo)
        pid = gains_for_geometry(design.pid, geo)
        return HandoverController(HandoverGains(lqr=lqr, pid=pid, max_tilt=pid.max_tilt, handover_mm=design.handover_mm,
                                                handover_mm_s=design.handover_mm_s, release_mm=design.release_mm,
                                                dt=dt, handover_dwell_s=design.handover_dwell_s,
                                                release_dwell_s=design.release_dwell_s,
                                                release_mm_s=design.release_mm_s,
                                                push_release_mm=design.push_release_mm),
                                  plate_half=half)  # fmt: skip
    if kind == "lqr":
        assert isinstance(design, LQRDesign)
        return LQRController(design_lqr(design, dt=dt, geometry=geo), plate_half=half)
    assert isinstance(design, PIDGains)
    return CascadedPID(gains_for_geometry(design, geo), dt=dt, plate_half=half)


def controller_from_gains(kind: str, gains: dict[str, Any],
                          plate_half: tuple[float, float] = (0.15, 0.15)) -> Any:  # fmt: skip
    """The controller of ``kind`` from gains as a bundle stores them (the fields of :class:`PIDGains`,
    :class:`LQRGains` or :class:`HandoverGains`, lists for tuples): no design step, numpy only. Raises
    ``KeyError``, ``TypeError`` or ``ValueError`` for malformed gains."""

    def lqr_gains(values: dict[str, Any]) -> LQRGains:
        lqr = LQRGains(**{**values, "k": tuple(float(v) for v in values["k"])})
        if len(lqr.k) != 5:
            raise TypeError(f"k has {len(lqr.k)} gains, expected 5")
        return lqr

    if kind == "pid":
        return CascadedPID(PIDGains(**gains), plate_half=plate_half)
    if kind == "lqr":
        return LQRController(lqr_gains(gains), plate_half=plate_half)
    if kind == "handover":
        rest = {k: v for k, v in gains.items() if k not in ("lqr", "pid")}
        return HandoverController(HandoverGains(lqr=lqr_gains(gains["lqr"]), pid=PIDGains(**gains["pid"]), **rest),
                                  plate_half=plate_half)  # fmt: skip
    raise ValueError(f"unknown classical kind {kind!r} (expected one of {list(CLASSICAL_KINDS)})")
