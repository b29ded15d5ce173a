"""Evaluate a policy on seeded episodes: success, ball error, settling time, tilt, servo wear.

A *policy* is anything with ``predict(obs, state, episode_start, deterministic)``
(Stable-Baselines3 models, :class:`~stewart_gym.control.CascadedPID`, the
ONNX bundle); :func:`stewart_gym.registry.load_policy` builds one from what a
user names. The same code runs the RL policy and the classical baseline on the same
seeds.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from stewart_gym.envs.ball_env import settling_start
from stewart_gym.errors import PolicyError
from stewart_gym.outputs import make_parent

__all__ = ["GIF_FPS", "MIN_VERDICT_EPISODES", "PAIRED_METRICS", "EpisodeLog", "Policy", "check_fits", "evaluate",
           "evaluation_part", "format_paired", "format_table", "paired_count", "paired_difference", "paired_rows",
           "paired_verdict", "plot_episode", "pooled_rms", "run_episode", "same_seeds", "settling_offset", "summarise",
           "write_gif"]  # fmt: skip


def settling_offset(env: gym.Env) -> float:
    """m: where the settling test starts on this env's plate: 100 mm on the reference plate, less on a smaller one
    (:func:`~stewart_gym.envs.ball_env.settling_start`)."""
    return settling_start(env.unwrapped.plate_half_extent)


class Policy(Protocol):
    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]: ...  # fmt: skip


#: Frames per second of an episode's GIF: its frames are rendered this often, to the nearest whole number of
#: control steps, and played in real time.
GIF_FPS = 25


@dataclass
class EpisodeLog:
    """One episode, sampled every control step (``dt`` s)."""

    dt: float
    distance_mm: list[float] = field(default_factory=list)
    ball_xy: list[np.ndarray] = field(default_factory=list)
    target_xy: list[np.ndarray] = field(default_factory=list)
    pulses: list[np.ndarray] = field(default_factory=list)
    tilt_deg: list[float] = field(default_factory=list)
    frames: list[np.ndarray] = field(default_factory=list)  # rendered every ``frame_every`` control steps
    frame_every: int = 1
    success: bool = False
    fell: bool = False
    plate_half_mm: tuple[float, float] = (150.0, 150.0)  # the plate's half width and depth (its edges), mm

    def settling_time(self, radius_mm: float) -> float:
        """s until the ball stays within ``radius_mm`` to the end; NaN if it never does (or fell)."""
        d = np.asarray(self.distance_mm)
        if self.fell or d.size == 0 or d[-1] > radius_mm:
            return math.nan
        outside = np.flatnonzero(d > radius_mm)
        return 0.0 if outside.size == 0 else float((outside[-1] + 1) * self.dt)


def run_episode(env: gym.Env, policy: Policy, seed: int, options: dict | None = None,
                frame_every: int = 0) -> EpisodeLog:  # fmt: skip
    """Run one episode to its end; record what the metrics need, and with ``frame_every`` k ≥ 1 a rendered frame
    after every k-th step (rendering is most of an episode's cost: render only what a GIF keeps)."""
    if isinstance(frame_every, bool) or not isinstance(frame_every, int) or frame_every < 0:
        raise ValueError(f"frame_every: 0 (no frames) or a whole number of steps, got {frame_every!r}")
    obs, info = env.reset(seed=seed, options=options)
    unwrapped = env.unwrapped
    log = EpisodeLog(dt=unwrapped.sim.dt, plate_half_mm=tuple(1e3 * float(h) for h in unwrapped.plate_half_extent),
                     frame_every=max(frame_every, 1))  # fmt: skip
    start = np.array([True])
    step = 0
    while True:
        action, _ = policy.predict(obs[None], None, start, True)
        start = np.array([False])
        obs, _, terminated, truncated, info = env.step(np.asarray(action, dtype=np.float32).reshape(-1))
        log.distance_mm.append(float(info["distance_mm"]))
        log.ball_xy.append(np.asarray(info["ball_xy_m"], dtype=float))
        log.target_xy.append(np.asarray(info["target_xy_m"], dtype=float))
        log.pulses.append(np.asarray(info["pulse_widths_us"], dtype=float))
        roll, pitch = info["commanded_tilt_rad"]
        log.tilt_deg.append(math.degrees(math.hypot(roll, pitch)))
        step += 1
        if frame_every and step % frame_every == 0:
            log.frames.append(env.render())
        if terminated or truncated:
            log.success = bool(info["is_success"])
            log.fell = bool(terminated)
            return log


def check_fits(policy: Policy, env: gym.Env) -> None:
    """Raise :class:`PolicyError` if the policy's observation or action size differs from the env's."""
    name = env.spec.id if env.spec else "the env"
    obs, act = getattr(policy, "obs_size", None), getattr(policy, "action_size", None)
    if obs is not None and (obs,) != env.observation_space.shape:
        raise PolicyError(f"the policy reads {obs} observation values but {name} gives {env.observation_space.shape[0]}")
    if act is not None and (act,) != env.action_space.shape:
        raise PolicyError(f"the policy gives {act} action values but {name} takes {env.action_space.shape[0]}")


def evaluate(env_id: str, policy: Policy, episodes: int = 100, seed: int = 0, randomize: bool = True,
             settling: bool = True, env_kwargs: dict | None = None,
             on_progress: Callable[[float], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Metrics over ``episodes`` seeded episodes (seeds ``seed … seed+episodes−1``); ``on_progress(amount)``
    is told of each part of an episode run (``episodes`` in all).

    * ``success_rate``: episodes whose last step reports ``is_success``.
    * ``rms_error_mm``: RMS ball-to-target distance over the last 5 s of every episode, pooled.
    * ``final_error_mm``: mean distance at the last step.
    * ``settling_time_s`` (fixed target): from rest at a standard 100 mm offset (2/3 of the half plate if
      that is less: ``settling_offset_mm`` says which)
      (direction varies with the seed), mean time until the ball stays within the
      success radius; ``settled_fraction`` says how many did.
    * ``max_tilt_deg``: largest commanded tilt; ``pulse_rate_us_per_s``: mean
      |ΔW| per servo per second (servo wear).
    * Settled servo activity, over the last 5 s of every episode that did not end
      with the ball off the plate: ``settled_pulse_rate_us_per_s`` (mean |ΔW| per
      servo per second) and ``settled_pulse_p2p_us`` (the largest channel's
      peak-to-peak, averaged over those episodes): how much the servos buzz once
      the ball is held.
    * ``per_episode``: per seed, in order: ``success``, ``rms_mm`` and ``tail_steps`` (each episode's RMS
      over its last 5 s and how many steps that was: the pooled RMS weighs them so), ``final_mm`` and
      ``settling_s`` (None where the ball did not settle): for paired comparisons on the same seeds
      (:func:`paired_difference`).

    It runs here, one episode after another; :func:`evaluation_part` and :func:`summarise` split the same
    evaluation over processes (``stewart-gym evaluate --workers``) with the same figures.
    """
    return summarise(env_id, episodes, seed, randomize,
                     [evaluation_part(env_id, policy, range(episodes), episodes, seed, randomize, settling, env_kwargs,
                                      on_progress)])  # fmt: skip


def evaluation_part(env_id: str, policy: Policy, indices: Sequence[int], episodes: int, seed: int = 0,
                    randomize: bool = True, settling: bool = True, env_kwargs: dict | None = None,
                    on_progress: Callable[[float], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Episodes ``indices`` (of ``range(episodes)``) of :func:`evaluate`'s evaluation, each reduced to what its
    figures need; :func:`summarise` of the parts, in order, gives those figures. Episode k is seeded
    ``seed + k`` and its settling run starts at the angle 2πk/episodes, and an episode does not depend on the
    ones run before it in the same env, so the parts can run anywhere (one per process) and give the figures of
    one :func:`evaluate`, to the last bit. ``on_progress(amount)`` after each run: 1 per episode in all (half
    for the episode and half for its settling run where there is one)."""
    env = gym.make(env_id, randomize=randomize, **(env_kwargs or {}))
    check_fits(policy, env)
    report = on_progress or (lambda amount: None)
    try:
        dt = env.unwrapped.sim.dt
        tail = int(round(5.0 / dt))
        settles = settling and not env.unwrapped.task.moving_target
        share = 0.5 if settles else 1.0
        records = []
        for k in indices:
            lg = run_episode(env, policy, seed + k)
            report(share)
            moved = len(lg.pulses) > 1
            records.append({"tail_mm": np.asarray(lg.distance_mm[-tail:]), "final_mm": lg.distance_mm[-1],
                            "success": lg.success, "fell": lg.fell, "max_tilt_deg": max(lg.tilt_deg),
                            "pulse_rate": np.abs(np.diff(np.asarray(lg.pulses), axis=0)).mean() / dt if moved else None,
                            "settled_pulses": np.asarray(lg.pulses[-tail:]) if moved and not lg.fell else None})  # fmt: skip
        offset = None
        if settles:
            radius_mm = env.unwrapped.success_radius * 1e3
            offset = settling_offset(env)
            for k, record in zip(indices, records):
                ang = 2 * math.pi * k / episodes
                opts = {"ball_position": (offset * math.cos(ang), offset * math.sin(ang)),
                        "ball_velocity": (0.0, 0.0)}  # fmt: skip
                record["settling_s"] = run_episode(env, policy, seed + k, opts).settling_time(radius_mm)
                report(share)
        return {"dt": dt, "settling_offset": offset, "records": records}
    finally:
        env.close()


def summarise(env_id: str, episodes: int, seed: int, randomize: bool, parts: list[dict[str, Any]]) -> dict[str, Any]:
    """:func:`evaluate`'s figures from :func:`evaluation_part`'s parts, which together hold its ``episodes``
    episodes in order."""
    records = [r for part in parts for r in part["records"]]
    if len(records) != episodes:
        raise ValueError(f"the parts hold {len(records)} episodes, not {episodes}")
    dt, offset = parts[0]["dt"], parts[0]["settling_offset"]
    pooled = np.concatenate([r["tail_mm"] for r in records])
    pulses = [r["pulse_rate"] for r in records if r["pulse_rate"] is not None]
    settled = [r["settled_pulses"] for r in records if r["settled_pulses"] is not None]
    out: dict[str, Any] = {
        "env_id": env_id,
        "episodes": episodes,
        "seed": seed,
        "randomize": randomize,
        "success_rate": float(np.mean([r["success"] for r in records])),
        "fell_rate": float(np.mean([r["fell"] for r in records])),
        "rms_error_mm": float(np.sqrt(np.mean(pooled**2))),
        "final_error_mm": float(np.mean([r["final_mm"] for r in records])),
        "max_tilt_deg": float(max(r["max_tilt_deg"] for r in records)),
        "pulse_rate_us_per_s": float(np.mean(pulses)),
        "settled_pulse_rate_us_per_s": (float(np.mean([np.abs(np.diff(w, axis=0)).mean() / dt for w in settled]))
                                        if settled else None),
        "settled_pulse_p2p_us": float(np.mean([np.ptp(w, axis=0).max() for w in settled])) if settled else None,
        "settling_time_s": None,
        "settled_fraction": None,
        "per_episode": {
            "success": [bool(r["success"]) for r in records],
            "rms_mm": [float(np.sqrt(np.mean(np.square(r["tail_mm"])))) for r in records],
            "tail_steps": [len(r["tail_mm"]) for r in records],
            "final_mm": [float(r["final_mm"]) for r in records],
            "settling_s": None,
        },
    }
    if offset is not None:
        t = np.asarray([r["settling_s"] for r in records])
        out["settled_fraction"] = float(np.mean(np.isfinite(t)))
        out["settling_offset_mm"] = round(offset * 1e3, 1)
        out["settling_time_s"] = float(np.nanmean(t)) if np.isfinite(t).any() else None
        out["per_episode"]["settling_s"] = [float(v) if math.isfinite(v) else None for v in t]
    return out


#: What :func:`paired_difference` compares: the metrics whose per-episode values ``per_episode`` keeps.
PAIRED_METRICS = ("success_rate", "rms_error_mm", "final_error_mm", "settling_time_s")


def pooled_rms(rms_mm: Any, tail_steps: Any) -> Any:
    """The RMS over several episodes' last 5 s together, as ``evaluate``'s ``rms_error_mm``: each episode's RMS
    (``per_episode["rms_mm"]``) weighed by its steps (``tail_steps``), over the last axis."""
    rms, n = np.asarray(rms_mm, dtype=float), np.asarray(tail_steps, dtype=float)
    return np.sqrt((n * rms**2).sum(axis=-1) / n.sum(axis=-1))


def _paired_statistic(per_episode: dict[str, Any], metric: str, index: np.ndarray) -> np.ndarray:
    """The metric of ``evaluate`` recomputed from its per-episode values, for each row of episode indices."""
    if metric == "success_rate":
        return np.asarray(per_episode["success"], dtype=float)[index].mean(axis=-1)
    if metric == "rms_error_mm":
        rms, n = np.asarray(per_episode["rms_mm"], dtype=float), np.asarray(per_episode["tail_steps"], dtype=float)
        return pooled_rms(rms[index], n[index])
    if metric == "final_error_mm":
        return np.asarray(per_episode["final_mm"], dtype=float)[index].mean(axis=-1)
    if metric == "settling_time_s":
        t = np.array([np.nan if v is None else v for v in per_episode["settling_s"]], dtype=float)[index]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a resample in which none settled: NaN
            return np.nanmean(t, axis=-1)
    raise ValueError(f"metric must be one of {PAIRED_METRICS}, got {metric!r}")


def same_seeds(a: dict[str, Any] | None, b: dict[str, Any] | None) -> bool:
    """Whether two ``evaluate`` results kept each seed's values on the same seeds, so that
    :func:`paired_difference` can pair them."""
    if not (a and b and "per_episode" in a and "per_episode" in b):
        return False
    return len(a["per_episode"]["success"]) == len(b["per_episode"]["success"]) and a.get("seed") == b.get("seed")


def paired_difference(a: dict[str, Any], b: dict[str, Any], metric: str, resamples: int = 2000,
                      level: float = 0.95, seed: int = 0) -> tuple[float, float, float]:  # fmt: skip
    """``metric`` of ``a`` minus that of ``b`` — two ``evaluate`` results on the same seeds — with a paired
    bootstrap interval: (difference, low, high). Episodes are resampled together (seed k of ``a`` with seed
    k of ``b``), so what the seeds share (start, trims, noise) cancels; an interval that holds 0 is a tie at
    this many episodes. Settling time is each resample's mean over the episodes where both settled."""
    if not same_seeds(a, b):
        raise ValueError("paired comparison needs two evaluations on the same seeds")
    pa, pb = a["per_episode"], b["per_episode"]
    if metric == "settling_time_s":
        both = [x is not None and y is not None for x, y in zip(pa["settling_s"], pb["settling_s"])]
        pa = {**pa, "settling_s": [x if ok else None for x, ok in zip(pa["settling_s"], both)]}
        pb = {**pb, "settling_s": [y if ok else None for y, ok in zip(pb["settling_s"], both)]}
    n = len(pa["success"])
    everything = np.arange(n)[None]
    diff = float((_paired_statistic(pa, metric, everything) - _paired_statistic(pb, metric, everything))[0])
    index = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    boot = _paired_statistic(pa, metric, index) - _paired_statistic(pb, metric, index)
    boot = boot[np.isfinite(boot)]
    low, high = np.quantile(boot, [(1 - level) / 2, (1 + level) / 2]) if boot.size else (math.nan, math.nan)
    return diff, float(low), float(high)


def paired_count(a: dict[str, Any], b: dict[str, Any], metric: str) -> int:
    """How many episodes :func:`paired_difference` pairs for ``metric``: every seed, or for settling time the seeds
    where both settled."""
    pa, pb = a["per_episode"], b["per_episode"]
    if metric == "settling_time_s":
        return sum(x is not None and y is not None for x, y in zip(pa["settling_s"], pb["settling_s"]))
    return len(pa["success"])


#: The fewest paired episodes a verdict is given on: with fewer, a bootstrap interval is little more than the
#: smallest and largest difference (with two, any two of one sign would be "better" or "worse"), not a 95 % one.
MIN_VERDICT_EPISODES = 10


def paired_verdict(metric: str, low: float, high: float, pairs: int = MIN_VERDICT_EPISODES) -> str:
    """What a paired interval of ``metric`` (row a minus row b, :func:`paired_difference`, over ``pairs`` paired
    episodes) says of a: ``better`` or ``worse`` when it excludes 0 (a higher success rate is better; a lower
    error or settling time), ``tie`` when it holds 0, ``–`` when it could not be computed (no seed where both
    settled), and ``too few episodes`` below :data:`MIN_VERDICT_EPISODES` pairs."""
    if not (math.isfinite(low) and math.isfinite(high)):
        return "–"
    if pairs < MIN_VERDICT_EPISODES:
        return f"too few episodes ({pairs} < {MIN_VERDICT_EPISODES})"
    if low <= 0 <= high:
        return "tie"
    lower_is_better = metric != "success_rate"
    return "better" if (high < 0) == lower_is_better else "worse"


def paired_rows(results: dict[str, dict[str, Any]], reference: str) -> list[dict[str, Any]]:
    """``reference`` paired with each other result of ``results`` (name → an ``evaluate`` result, all on the same
    seeds): one row per other result and metric of :data:`PAIRED_METRICS` that both measured, with ``a``, ``b``,
    ``metric``, ``difference`` (a − b), ``low``, ``high`` (the 95 % bootstrap interval) and ``verdict``
    (:func:`paired_verdict`). Settling time only where both ran the settling test."""
    rows = []
    for other in results:
        if other == reference:
            continue
        for metric in PAIRED_METRICS:
            if metric == "settling_time_s" and not all(results[n]["per_episode"].get("settling_s") is not None
                                                       for n in (reference, other)):  # fmt: skip
                continue
            diff, low, high = paired_difference(results[reference], results[other], metric)
            pairs = paired_count(results[reference], results[other], metric)
            rows.append({"a": reference, "b": other, "metric": metric, "difference": diff, "low": low, "high": high,
                         "verdict": paired_verdict(metric, low, high, pairs)})  # fmt: skip
    return rows


#: How :func:`format_paired` writes each metric's difference: a label, a scale, a number format and a unit.
PAIRED_FORMATS = {"success_rate": ("success rate", 100.0, "{:+.0f}", "% points"),
                  "rms_error_mm": ("RMS error (last 5 s)", 1.0, "{:+.2f}", "mm"),
                  "final_error_mm": ("final error", 1.0, "{:+.2f}", "mm"),
                  "settling_time_s": ("settling time", 1.0, "{:+.2f}", "s")}  # fmt: skip


def format_paired(rows: list[dict[str, Any]]) -> str:
    """:func:`paired_rows` as text: per pair, each metric's difference, its interval and the verdict."""
    lines = []
    for pair in dict.fromkeys((r["a"], r["b"]) for r in rows):
        lines.append(f"{pair[0]} − {pair[1]}, seed by seed: difference [95 % bootstrap interval], verdict")
        for r in (r for r in rows if (r["a"], r["b"]) == pair):
            label, scale, pattern, unit = PAIRED_FORMATS[r["metric"]]
            diff, low, high = (pattern.format(v * scale) if math.isfinite(v) else "–"
                               for v in (r["difference"], r["low"], r["high"]))  # fmt: skip
            interval = f"[{low}, {high}]"
            lines.append(f"  {label:24s}{diff:>7s} {interval:18s} {unit:8s} {r['verdict']}")
    return "\n".join(lines)


def format_table(results: dict[str, dict[str, Any]]) -> str:
    """A text table with one column per policy."""
    offsets = {r.get("settling_offset_mm") for r in results.values()} - {None}
    start = f"{offsets.pop():g} mm start" if len(offsets) == 1 else "start as listed"
    rows = [("success rate", "success_rate", "{:.0%}"), ("fell off", "fell_rate", "{:.0%}"),
            ("RMS error (last 5 s)", "rms_error_mm", "{:.2f} mm"), ("final error", "final_error_mm", "{:.2f} mm"),
            (f"settling time ({start})", "settling_time_s", "{:.2f} s"), ("settled", "settled_fraction", "{:.0%}"),
            ("largest tilt", "max_tilt_deg", "{:.1f}°"),
            ("pulse rate (servo wear)", "pulse_rate_us_per_s", "{:.0f} µs/s"),
            ("settled pulse rate (last 5 s)", "settled_pulse_rate_us_per_s", "{:.0f} µs/s"),
            ("settled peak-to-peak", "settled_pulse_p2p_us", "{:.0f} µs")]  # fmt: skip
    names = list(results)
    width = max(12, *(len(n) for n in names))
    lines = [f"{'':30s}" + "".join(f"{n:>{width + 2}s}" for n in names)]
    for label, key, fmt in rows:
        cells = []
        for n in names:
            v = results[n].get(key)
            cells.append(f"{'—' if v is None else fmt.format(v):>{width + 2}s}")
        lines.append(f"{label:30s}" + "".join(cells))
    return "\n".join(lines)


# ------------------------------------------------------------------- figures
def plot_episode(log: EpisodeLog, path: str | Path, title: str = "") -> None:
    """Ball path on the plate and the six pulse widths over time, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xy, tgt, w = np.asarray(log.ball_xy) * 1e3, np.asarray(log.target_xy) * 1e3, np.asarray(log.pulses)
    t = np.arange(len(w)) * log.dt
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5), gridspec_kw={"width_ratios": [1, 1.5]})
    hx, hy = log.plate_half_mm
    ax1.add_patch(plt.Rectangle((-hx, -hy), 2 * hx, 2 * hy, fill=False, color="0.5", lw=1.5, label="plate edge"))
    ax1.plot(xy[:, 0], xy[:, 1], lw=1.2, label="ball", zorder=2)
    if np.ptp(tgt, axis=0).max() > 1e-6:  # a moving target: its path
        ax1.plot(tgt[:, 0], tgt[:, 1], "k--", lw=0.8, label="target", zorder=3)
    else:  # a fixed one: a cross drawn over the ball's path
        ax1.plot(tgt[0, 0], tgt[0, 1], "r+", ms=14, mew=2, label="target", zorder=4)
    ax1.plot(xy[0, 0], xy[0, 1], "go", label="start", zorder=4)
    margin = 0.08 * max(hx, hy)
    ax1.set(xlim=(-hx - margin, hx + margin), ylim=(-hy - margin, hy + margin), xlabel="x on plate [mm]",
            ylabel="y on plate [mm]", aspect="equal")  # fmt: skip
    ax1.legend(loc="upper right", fontsize=8)
    for i in range(6):
        ax2.plot(t, w[:, i], lw=1, label=f"servo {i}")
    ax2.set(xlabel="time [s]", ylabel="pulse width [µs]", title="commanded pulse widths")
    ax2.legend(ncol=3, fontsize=8)
    ax2.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(make_parent(path), dpi=110)
    plt.close(fig)


def write_gif(frames: list[np.ndarray], path: str | Path, fps: float = GIF_FPS, dt: float | None = None,
              caption: str = "") -> None:  # fmt: skip
    """Write ``frames`` as an animated GIF at ``fps``; with ``dt`` (s between frames) each frame shows its time,
    after ``caption`` (what the target is, for one)."""
    import imageio.v3 as iio

    kept = frames
    if dt is not None:
        from PIL import Image, ImageDraw

        stamped = []
        for k, frame in enumerate(kept):
            image = Image.fromarray(np.ascontiguousarray(frame[..., :3]))
            text = f"t = {(k + 1) * dt:4.1f} s" + (f"   {caption}" if caption else "")
            draw = ImageDraw.Draw(image)
            draw.rectangle((4, 4, 8 + 6 * len(text), 18), fill=(255, 255, 255))
            draw.text((6, 5), text, fill=(0, 0, 0))
            stamped.append(np.asarray(image))
        kept = stamped
    # encoded in memory, then written: imageio's writer, failing to open a path, fails again when collected
    data = iio.imwrite("<bytes>", np.stack(kept), extension=".gif", duration=1000 / fps, loop=0)
    make_parent(path).write_bytes(data)
