"""The ball environments: one class, :class:`StewartBallEnv`, made of a physics backend, a ball sensor,
the action mapping and a task (panda-gym's Robot/Task/RobotTaskEnv split)."""

from __future__ import annotations

import copy
import math
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ClosedEnvironmentError, ResetNeeded
from gymnasium.utils import EzPickle

from stewart_gym.actions import ActionMapper
from stewart_gym.camera import CAMERA_PRESETS, CameraSpec, SimulatedCamera
from stewart_gym.envs.arguments import (
    MAX_EPISODE_S,
    check_engine_arguments,
    check_randomization,
    number_range,
    real_number,
    true_or_false,
)
from stewart_gym.envs.randomization import EpisodeParams, RandomizationRanges, draw_count, polar
from stewart_gym.envs.task import Task, load_task, task_keywords
from stewart_gym.errors import ConfigError
from stewart_gym.sensing import ESTIMATORS, BallObserver, SimulatedTouchPanel, TouchPanelSpec, ball_contact
from stewart_gym.sim import BallSpec, PhysicsBackend, ServoSpec
from stewart_gym.sim.backend import missing_members
from stewart_gym.sim.engines import BACKEND_NAMES, make_backend
from stewart_gym.sim.servo_model import LINEAR_ACTUATOR
from stewart_gym.sim.twin import Twin, load_twin

__all__ = ["DEFAULT_SUCCESS_WINDOW_S", "StewartBallEnv", "check_ball_geometry", "settling_start"]

#: m: where the settling-time test starts (:mod:`stewart_gym.evaluation`) on a plate large enough.
SETTLING_OFFSET = 0.100
#: On a smaller plate it starts this fraction of the plate's smaller half size out (0.100 m on the 300 mm plate).
SETTLING_FRACTION = 2.0 / 3.0


def settling_start(plate_half_extent: Sequence[float]) -> float:
    """m: how far from the target the settling test starts on a plate of this half size (m, along x and y)."""
    return min(SETTLING_OFFSET, SETTLING_FRACTION * min(plate_half_extent))

#: A plate must be at least this many ball diameters a side to carry the ball task.
MIN_PLATE_BALLS = 4
#: The platform must tilt its plate at least this much (rad) to move the ball.
MIN_TILT = math.radians(2.0)


#: ``sensor=`` names: the touch panel, a camera preset, or "camera" (one of the presets per randomised episode).
SENSOR_NAMES = ("panel", "camera", *CAMERA_PRESETS)


def sensor_spec(sensor: TouchPanelSpec | CameraSpec | str | None) -> TouchPanelSpec | CameraSpec | tuple:
    """The sensor an env is built with: a spec, or for ``"camera"`` the tuple of camera presets (the first,
    the webcam, when not randomised)."""
    if sensor is None or sensor == "panel":
        return TouchPanelSpec()
    if sensor == "camera":
        return (CAMERA_PRESETS["webcam30"], CAMERA_PRESETS["pixy2"], CAMERA_PRESETS["global90"])
    if isinstance(sensor, str):
        if sensor not in CAMERA_PRESETS:
            raise ConfigError(f"sensor must be one of {list(SENSOR_NAMES)}, a TouchPanelSpec or a CameraSpec, "
                              f"got {sensor!r}")  # fmt: skip
        return CAMERA_PRESETS[sensor]
    if not isinstance(sensor, (TouchPanelSpec, CameraSpec)):
        raise ConfigError(f"sensor must be one of {list(SENSOR_NAMES)}, a TouchPanelSpec or a CameraSpec, "
                          f"got {sensor!r}")  # fmt: skip
    return sensor


def sensor_model(spec: TouchPanelSpec | CameraSpec | tuple,
                 ball_radius: float) -> SimulatedTouchPanel | SimulatedCamera:  # fmt: skip
    """The simulated sensor for a spec (a tuple of cameras: its first)."""
    spec = spec[0] if isinstance(spec, tuple) else spec
    if isinstance(spec, CameraSpec):
        return SimulatedCamera(spec, ball_radius)
    return SimulatedTouchPanel(spec)


@dataclass(frozen=True)
class EpisodeReplay:
    """What a copy of an env replays of its episode (:meth:`StewartBallEnv.__deepcopy__`): the generator's state at
    the reset, the reset's options (a copy), the actions taken since, and the start box and the task as they were at
    the reset (a shallow copy: its settings then)."""

    draws: dict
    options: Any
    actions: list[np.ndarray]
    start_fraction: float
    task: Any


def check_ball_geometry(geometry: Any, ball: BallSpec | None = None) -> Any:
    """The geometry, if it can carry the ball task; otherwise a :class:`~stewart_gym.geometry.GeometryError` saying
    why in one line (a plate too small for the ball, too little tilt)."""
    from stewart_gym.actions import default_max_tilt
    from stewart_gym.geometry import GeometryError
    from stewart_gym.presets import load_geometry

    geo = load_geometry(geometry)
    width, depth = geo.plate_extent
    diameter = 2 * (ball or BallSpec()).radius
    if min(width, depth) < MIN_PLATE_BALLS * diameter:
        raise GeometryError(f"the {width * 1e3:.0f} × {depth * 1e3:.0f} mm plate of {geo.name!r} is too small for a "
                            f"{diameter * 1e3:.1f} mm ball (at least {MIN_PLATE_BALLS * diameter * 1e3:.0f} mm a side)")
    tilt = default_max_tilt(geo)
    if tilt < MIN_TILT:
        raise GeometryError(f"{geo.name!r} tilts its plate by only {math.degrees(tilt):.1f}° from home: too little "
                            "to move a ball")  # fmt: skip
    return geo


#: s: the success window of an env made without one (or the whole episode where that is shorter).
DEFAULT_SUCCESS_WINDOW_S = 1.0


class StewartBallEnv(gym.Env, EzPickle):
    """A ball rolling on the plate of a six-servo Stewart platform, given a task.

    Every registered id is this class with a task (:mod:`stewart_gym.envs.task`):
    ``StewartBallBalance-v0`` (:class:`~stewart_gym.envs.tasks.balance.BalanceTask`),
    ``StewartBallTrack-v0`` (:class:`~stewart_gym.envs.tasks.track.TrackTask`) and
    ``StewartBallDisturbance-v0``
    (:class:`~stewart_gym.envs.tasks.disturbance.DisturbanceTask`).

    ## Description
    A PyBullet model of a hobby servo hexapod (``servo-hexapod``: MG996R
    servos, 25 mm horns, 160 mm rods, 300 × 300 mm plate; all six loops closed)
    carries a ball (default a 25.4 mm, 66.8 g solid steel ball, the kind a
    resistive touch panel senses). The agent tilts the plate to bring the ball
    to a target. Every action goes through the analytic inverse kinematics and
    the servo calibration to pulse widths (µs), exactly as on hardware; the
    simulated servos act on those pulses with hobby-servo speed, dead band and
    lag. The ball is sensed as a resistive touch panel would report it, or a camera (``sensor=``).

    ## Action Space
    ``Box(-1, 1, (n,), float32)``; ``action_mode`` picks the mapping:

    ACTION_TABLE

    A commanded pose that is out of reach is replaced by the nearest reachable
    pose on the ray from home; ``info["action_scaled"]`` flags it and
    ``info["unreachable_count"]`` counts it over the episode.

    ## Observation Space
    ``Box(float32)`` of size 10 + n, 12 + n with ``integral=True``
    (:class:`~stewart_gym.sensing.ObservationBuilder`), each entry divided by its scale and clipped, so about ±1:

    OBSERVATION_TABLE

    The panel (:class:`~stewart_gym.sensing.TouchPanelSpec`) samples at 100 Hz
    with 10 ms latency and 1 mm noise; when the ball is not touching, the last
    reading is held. Velocity is a low-passed finite difference of readings.

    ## Rewards
    The task's (:meth:`~stewart_gym.envs.task.BallTask.reward`); for every
    built-in task, per step, with d the true ball-to-target distance (m):
    ``1 − d / 0.15 + exp(−d / 0.015) − rate_penalty · mean((a_t − a_{t−1})²)``:
    a distance term over the whole plate, a sharper one near the target (0.51 at
    10 mm, 1 at 0; ``near_scale`` sets the 0.015 m), and an action-rate penalty for servo wear
    (``rate_penalty``, default 0.1, plus ``settled_rate_penalty`` within the success radius);
    ``outside_penalty`` (default 0) per step while the ball is beyond the success radius (with
    ``charge_until_settled``, also for the steps it spent inside before leaving again: the settling time);
    ``−50`` on the step the ball leaves the plate.

    ## Starting State
    Platform at home. The ball rests on the plate at a uniform random position
    within 2/3 of the plate's half size of the centre on each axis (±0.10 m on
    the 300 mm plate) rolling at a uniform random speed up to 0.1 m/s in a
    random direction; with ``start_distance=(low, high)`` (m) it starts instead at a uniform random distance in
    that range from the centre, in a uniform random direction (to train the approach from afar).
    ``reset(options={"ball_position": (x, y), "ball_velocity":
    (vx, vy)})`` sets them (m, m/s, plate frame); they are checked: two finite
    numbers each, the ball's centre at most half the plate minus its radius from
    the centre on each axis, at most 2 m/s, and no other keys
    (:class:`~stewart_gym.errors.ConfigError` otherwise).

    ## Episode End
    ``terminated`` when the ball centre leaves the plate (|x| or |y| beyond half its size)
    or drops below its surface, or when the physics blows up (non-finite or
    absurd state: ``info["physics_error"]`` is True and the last finite
    observation is returned). ``truncated`` after ``episode_s`` seconds (balance and the pushes 10 s, track
    20 s: 500 and 1000 steps at the default 50 Hz, half as many at ``control_hz=25``); ``gym.make(…,
    max_episode_steps=N)`` adds a shorter limit. ``info["is_success"]`` (every
    step) is true while the ball is on the plate and has stayed within the
    task's ``success_radius`` of the target for the last ``success_window_s``.
    ``info`` also gives ``distance_mm``, ``ball_xy_m``, ``target_xy_m``,
    ``pulse_widths_us``, ``commanded_tilt_rad`` (roll, pitch), ``action_scaled``,
    ``unreachable_count``, ``physics_error`` and the task's own entries. Every entry is a NumPy value (scalars
    as ``np.bool_``, ``np.float64``, ``np.int64``), so that clients which read ``info`` by dtype (TorchRL's
    ``auto_register_info_dict``) take it as it is.

    ## Arguments
    ``task`` (a short name, a ``"module:Class"`` path or a task object),
    ``action_mode``, ``randomize`` (domain randomisation, see
    :class:`~stewart_gym.envs.randomization.RandomizationRanges`; ``randomization`` takes the ranges or a
    mapping of the fields to change),
    ``render_mode`` (``"rgb_array"`` or ``"human"``), ``max_tilt`` (rad),
    ``success_radius`` (m), ``success_window_s`` (s, no longer than the episode; default 1, or the whole episode
    where that is shorter), ``physics_hz`` (default
    the engine's: PyBullet 150 Hz, trading the simulator's 200 Hz, loop gap ≤ 0.07 mm
    in full-range moves, for speed; at 150 Hz the gap is ≤ 0.12 mm in full-range moves
    and ≤ 0.042 mm under ±10° bang-bang tilts; MuJoCo 250 Hz), ``control_hz``, ``rate_penalty``,
    ``ball`` (:class:`~stewart_gym.sim.BallSpec`), ``servo``
    (:class:`~stewart_gym.sim.ServoSpec`), ``sensor`` (a
    :class:`~stewart_gym.sensing.TouchPanelSpec`, a :class:`~stewart_gym.camera.CameraSpec`,
    ``"panel"``, a camera preset ``"pixy2"``, ``"webcam30"``, ``"global90"``, or
    ``"camera"``: a preset per randomised episode), ``geometry``,
    ``backend`` (``"auto"``, the default: PyBullet where it imports, else MuJoCo; ``"pybullet"`` or
    ``"mujoco"``: the same env in either engine; or a :class:`~stewart_gym.sim.PhysicsBackend` object),
    ``estimator``
    (``"lowpass"``, the default: the last reading and a filtered finite-difference velocity; or
    ``"kalman"``: :class:`~stewart_gym.sensing.BallKalmanFilter`'s estimate for now, through the sensing
    delay), ``integral`` (append the observer's integral of the position error near the target, what a
    PID's integral term sees), ``start_distance`` (see Starting State), ``episode_s`` (s, the episode's length;
    each id sets its own), ``twin`` (a twin file, :class:`~stewart_gym.sim.twin.Twin` or its tables: the
    simulated platform has exactly its parameters; with ``randomize``, each is drawn narrowly around them, see
    :data:`~stewart_gym.envs.randomization.TWIN_WIDTH_FLOOR`), and any keyword of the task
    (``trajectory`` for track; ``near_scale``, ``settled_rate_penalty``, ``outside_penalty`` and
    ``charge_until_settled`` of the reward).

    ## Version History
    * v0: initial release (``StewartBallDisturbance-v0`` added later, same version).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}

    def __init__(
        self,
        task: str | Task = "balance",
        action_mode: Literal["tilt", "pose", "pulse"] = "tilt",
        randomize: bool = False,
        render_mode: str | None = None,
        *,
        max_tilt: float | None = None,
        success_radius: float | None = None,
        success_window_s: float | None = None,
        physics_hz: int | None = None,
        control_hz: int = 50,
        ball: BallSpec | None = None,
        servo: ServoSpec | None = None,
        sensor: TouchPanelSpec | CameraSpec | str | None = None,
        geometry: Any = "servo-hexapod",
        randomization: RandomizationRanges | Mapping[str, Any] | None = None,
        rate_penalty: float = 0.1,
        backend: PhysicsBackend | str = "auto",
        estimator: str = "lowpass",
        integral: bool = False,
        start_distance: Sequence[float] | None = None,
        episode_s: float = 10.0,
        twin: Twin | Mapping[str, Any] | str | None = None,
        **task_kwargs: Any,
    ) -> None:
        EzPickle.__init__(self, task, action_mode, randomize, render_mode, max_tilt=max_tilt,
                          success_radius=success_radius, success_window_s=success_window_s, physics_hz=physics_hz,
                          control_hz=control_hz, ball=ball, servo=servo, sensor=sensor, geometry=geometry,
                          randomization=randomization, rate_penalty=rate_penalty, backend=backend,
                          estimator=estimator, integral=integral, start_distance=start_distance,
                          episode_s=episode_s, twin=twin, **task_kwargs)  # fmt: skip
        unknown = sorted(set(task_kwargs) - task_keywords(task)) if isinstance(task, str) else sorted(task_kwargs)
        if unknown:  # a TypeError, as Python's own for a keyword a function does not take (clients probe for it)
            raise TypeError(f"{type(self).__name__}.__init__() got an unexpected keyword argument {unknown[0]!r} "
                            f"(the env and its task take: {', '.join(sorted(env_keywords(task)))})")  # fmt: skip
        episode_s = real_number("episode_s", episode_s, low=0, high=MAX_EPISODE_S, low_open=True)
        control_hz, physics_hz = check_engine_arguments(geometry, control_hz, physics_hz, ball, servo)
        max_tilt = real_number("max_tilt", max_tilt, optional=True)  # (its range: the action mapper's)
        check_randomization(randomization)
        if not isinstance(backend, (str, PhysicsBackend)):
            missing = missing_members(backend)
            why = ("" if not missing else " (a class: pass an instance of it)" if isinstance(backend, type)
                   else f" (it lacks {', '.join(missing)})" if len(missing) < 10 else "")  # fmt: skip
            raise ConfigError(f"backend must be 'auto', one of {list(BACKEND_NAMES)} or a PhysicsBackend, got "
                              f"{backend!r}{why}")  # fmt: skip
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        if not (isinstance(randomize, (bool, np.bool_)) or (type(randomize) is int and randomize in (0, 1))):
            raise ConfigError(f"randomize must be true or false, got {randomize!r}")
        self.randomize = bool(randomize)
        self.render_mode = render_mode
        self.nominal_ball = ball or BallSpec()
        self.nominal_sensor = sensor_spec(sensor)
        if isinstance(randomization, Mapping):  # from YAML: the fields to change
            randomization = RandomizationRanges.from_mapping(randomization)
        self.ranges = randomization or RandomizationRanges()
        #: the platform simulated (:class:`~stewart_gym.sim.twin.Twin`), or None: the nominal one
        self.twin = None if twin is None else load_twin(twin)
        if isinstance(backend, str):
            geometry = check_ball_geometry(geometry, self.nominal_ball)
        rotary = (geometry if isinstance(backend, str) else backend.geometry).is_rotary
        self.nominal_servo = servo or (ServoSpec() if rotary else LINEAR_ACTUATOR)
        self.sim: PhysicsBackend = make_backend(
            backend, geometry, physics_hz=physics_hz, control_hz=control_hz, ball=True, ball_spec=self.nominal_ball,
            servo_spec=self.nominal_servo, render_mode=render_mode) if isinstance(backend, str) else backend  # fmt: skip
        # what this env can render here: "human" is PyBullet's window, which needs a display; "rgb_array" where the
        # engine gives frames (not the batched backend's reduced model)
        human = type(self.sim).__name__ == "StewartSim" and (not sys.platform.startswith("linux")
                                                             or bool(os.environ.get("DISPLAY")))  # fmt: skip
        frames = getattr(self.sim, "renders_frames", True)
        self.metadata = {**self.metadata, "render_fps": int(self.sim.control_hz),
                         "render_modes": ["human", "rgb_array"] if human else ["rgb_array"] if frames else []}  # fmt: skip
        self.plate_half_extent = tuple(self.sim.plate_half_extent)
        window = min(DEFAULT_SUCCESS_WINDOW_S, float(episode_s)) if success_window_s is None else success_window_s
        self.task: Task = load_task(task, success_radius=success_radius, success_window_s=window,
                                    rate_penalty=rate_penalty, plate_half=min(self.plate_half_extent),
                                    **task_kwargs) if isinstance(task, str) else task  # fmt: skip
        self.success_radius = float(self.task.success_radius)
        self.success_steps = max(1, int(round(self.task.success_window_s * self.sim.control_hz)))
        #: control steps in an episode: ``episode_s`` at this env's rate (then ``truncated``)
        self.episode_steps = max(1, int(round(float(episode_s) * self.sim.control_hz)))
        if self.success_steps > self.episode_steps:
            whose = "success_window_s" if isinstance(task, str) else "the task's success_window_s"
            raise ConfigError(f"{whose} ({self.task.success_window_s:g} s) is longer than the episode (episode_s "
                              f"{float(episode_s):g} s): no episode could succeed; give a shorter window or a longer "
                              "episode")  # fmt: skip
        self._engine = (backend, geometry, physics_hz, control_hz, render_mode) if isinstance(backend, str) else None
        self.mapper = ActionMapper(self.sim.geometry, self.sim.calibration, action_mode, max_tilt=max_tilt)
        self.action_mode = action_mode
        self.action_space = spaces.Box(-1.0, 1.0, (self.mapper.size,), dtype=np.float32)
        if estimator not in ESTIMATORS:
            raise ConfigError(f"estimator must be one of {list(ESTIMATORS)}, got {estimator!r}")
        integral = true_or_false("integral", integral)
        self.start_distance = self._checked_start_distance(start_distance)
        self.observer = BallObserver(self.mapper.size, plate_half=self.plate_half_extent, estimator=estimator,
                                     integral=integral)  # fmt: skip
        self.observation_space = self.observer.builder.space
        self.sensor_model = sensor_model(self.nominal_sensor, self.nominal_ball.radius)
        self._plate_top = self.sim.plate_top
        self._episode: EpisodeReplay | None = None
        self._last_obs = np.zeros(self.observation_space.shape, dtype=np.float32)  # the last observation returned
        self._reset_episode_state()

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        xy, velocity = self.draw_episode(seed=seed, options=options)
        params, rng = self.params, self.np_random
        self.sim.reset(servo_spec=params.servo, ball_spec=params.ball, plate_friction=params.plate_friction,
                       plate_load=params.plate_load)  # fmt: skip
        self.sim.place_ball(xy, velocity)
        self.task.reset(rng, self.sim)
        if type(params.sensor) is not type(self.sensor_model.spec):
            self.sensor_model = sensor_model(params.sensor, params.ball.radius)
        self.sensor_model.spec = params.sensor
        if isinstance(params.sensor, CameraSpec):
            self.sensor_model.ball_radius = params.ball.radius
        self.sensor_model.reset(0.0, xy, rng)
        self.observer.reset(0.0, xy)
        obs = self._last_obs = self._observe(0.0)
        target_xy, _ = self.task.target(0.0)
        return obs, self._info(xy.copy(), target_xy, distance(xy[0] - target_xy[0], xy[1] - target_xy[1]))

    def draw_episode(self, *, seed: int | None = None,
                     options: dict[str, Any] | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """The start of :meth:`reset`: seed the generator (``seed``), check ``options``, draw the episode's
        parameters (:attr:`params`) and the ball's start, and start this env's own count of the episode. Returns the
        ball's start, (x, y) m and velocity m/s. The rest of the reset (the physics, the task's draws, the sensor, the
        observer and the first observation) follows in :meth:`reset`, or, for the batched vector env's copies, for all
        the copies it resets at once (:class:`~stewart_gym.envs.vector.StewartBallVectorEnv`)."""
        checked = self.begin_episode(seed, options)
        rng = self.np_random
        if self.twin is not None:
            params = EpisodeParams.from_twin(self.twin, self.nominal_ball, self.nominal_servo, self.nominal_sensor,
                                             rng if self.randomize else None, self.ranges)  # fmt: skip
        elif self.randomize:
            params = EpisodeParams.sample(rng, self.ranges, self.nominal_ball, self.nominal_servo, self.nominal_sensor)
        else:
            nominal = self.nominal_sensor[0] if isinstance(self.nominal_sensor, tuple) else self.nominal_sensor
            params = EpisodeParams(self.nominal_ball, self.nominal_servo, nominal, 0.6, None)
        self.keep_params(params)
        xy, velocity = self.ball_starts(self.np_random.random(self.start_draw_count(checked))[None], checked)
        return xy[0], velocity[0]

    @staticmethod
    def draw_episodes(envs: Sequence[StewartBallEnv], seeds: Sequence[int | None],
                      options: dict[str, Any] | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """:meth:`draw_episode` of each of ``envs``, env k seeded ``seeds[k]``: the same draws from each env's own
        generator, in the same order, and the same episodes; the balls' starts as arrays, (x, y) m and velocities
        m/s (a row each). The envs whose parameters are drawn around one sensor (``randomize``, no twin, a touch
        panel or one camera) take their draws from one generator call each, and those with the same settings
        (:meth:`draw_settings`: each env's own, as a curriculum may set them on some) have their arithmetic done
        together (:meth:`EpisodeParams.from_draws <stewart_gym.envs.randomization.EpisodeParams.from_draws>`, and
        the starts')."""
        xy, velocity = np.empty((len(envs), 2)), np.empty((len(envs), 2))
        groups: list[tuple[tuple, list[int]]] = []  # (settings, the envs with them), in the order first met
        for k, env in enumerate(envs):
            settings = env.draw_settings()
            if settings is None:  # drawn env by env
                xy[k], velocity[k] = env.draw_episode(seed=seeds[k], options=options)
                continue
            for known, members in groups:
                if known == settings:
                    members.append(k)
                    break
            else:
                groups.append((settings, [k]))
        for _, members in groups:
            together = [envs[k] for k in members]
            first = together[0]
            checked = [env.begin_episode(seeds[k], options) for env, k in zip(together, members)]
            count = draw_count(first.nominal_sensor)
            size = count + first.start_draw_count(checked[0])  # (the same options for all)
            draws = np.array([env.np_random.random(size) for env in together])
            params = EpisodeParams.from_draws(draws[:, :count], first.ranges, first.nominal_ball,
                                              first.nominal_servo, first.nominal_sensor)  # fmt: skip
            for env, p in zip(together, params):
                env.keep_params(p)
            xy[members], velocity[members] = first.ball_starts(draws[:, count:], checked[0])
        return xy, velocity

    def draw_settings(self) -> tuple | None:
        """What this env's episode draws depend on besides its generator, where they come from one generator call
        (``randomize``, no twin, a touch panel or one camera): its ranges, nominal ball, servos and sensor, the
        ball's start distance and the plate's size; None otherwise. Envs with equal settings draw together
        (:meth:`draw_episodes`)."""
        if self.twin is not None or not self.randomize or isinstance(self.nominal_sensor, tuple):
            return None
        return (self.ranges, self.nominal_ball, self.nominal_servo, self.nominal_sensor, self.start_distance,
                self.plate_half_extent)  # fmt: skip

    def begin_episode(self, seed: int | None, options: dict[str, Any] | None) -> dict[str, np.ndarray]:
        """:meth:`draw_episode` before the draws: seed the generator, note what a copy replays, check the options
        (returned, as arrays) and start a closed engine again. Options it refuses leave no trace: the generator, the
        episode and what a copy replays are as they were."""
        checked = self._check_options(options)
        super().reset(seed=seed)
        if getattr(self.sim, "closed", False):  # reset after close(): the engine starts again, as Gymnasium's envs do
            self._reopen()
        #: what a copy replays (:meth:`__deepcopy__`); None on a backend object (such an env cannot be copied)
        self._episode = None if self._engine is None else EpisodeReplay(
            self.np_random.bit_generator.state, copy.deepcopy(options), [], self.START_FRACTION,
            copy.copy(self.task))  # fmt: skip  (its settings now: a copy deepcopies it, never a reset)
        return checked

    def _own_parts(self, owner: StewartBallEnv) -> dict[int, Any]:
        """A deep copy's memo that gives ``owner``'s env, engine and generator where this env's are met (and the
        engine closed before the last reset, which a task may hold from the last episode): a task that holds them
        holds ``owner``'s (this env's own: a snapshot shares them)."""
        memo = {id(self): owner, id(self.sim): owner.sim, id(self.np_random): owner.np_random}
        closed = getattr(self, "_closed_sim", None)
        if closed is not None:
            memo[id(closed)] = owner.sim
        return memo

    @staticmethod
    def _copied_task(task: Task, memo: dict[int, Any]) -> Task:
        """A deep copy of ``task`` (``memo``: :meth:`_own_parts`, not filled in); a ``TypeError`` that says why where
        it cannot be copied (a lock, an open file among a user's task's members)."""
        try:
            return copy.deepcopy(task, dict(memo))
        except Exception as exc:  # noqa: BLE001  (a user's task: whatever its members raise)
            raise TypeError(f"copy.deepcopy: this env's task ({type(task).__name__}) cannot be copied "
                            f"({type(exc).__name__}: {exc}); give the task a __deepcopy__, or make another env "
                            "with gym.make") from None  # fmt: skip

    def keep_params(self, params: EpisodeParams) -> None:
        """:meth:`draw_episode` after the parameters' draws: keep ``params`` and start this env's own count of the
        episode."""
        #: this episode's physical parameters
        self.params = params
        self._radius = params.ball.radius
        self._reset_episode_state()

    @staticmethod
    def start_draw_count(options: dict[str, np.ndarray]) -> int:
        """How many uniform draws the ball's start takes with ``options`` (checked): two for a position, two for a
        velocity, each unless given."""
        return 2 * ("ball_position" not in options) + 2 * ("ball_velocity" not in options)

    def ball_starts(self, draws: np.ndarray, options: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The balls' starts (x, y) m and velocities m/s (a row each) from ``options`` where given, else from rows of
        uniform draws in [0, 1) (m × :meth:`start_draw_count`) (see Starting State). Each number is low + (high − low) ·
        d, what a call of ``rng.uniform(low, high)`` per number gives, up to NumPy's rounding (as
        :class:`~stewart_gym.envs.randomization.EpisodeParams`' draws; ``tests/envs/test_envs.py``)."""
        m = len(draws)
        position, velocity = options.get("ball_position"), options.get("ball_velocity")
        if position is None:
            d0, d1 = draws[:, 0], draws[:, 1]
            draws = draws[:, 2:]
            if self.start_distance is not None:  # a distance within the range, in a uniform direction
                low, high = self.start_distance
                xy = polar(low + (high - low) * d0, 2 * math.pi * d1)
            else:  # uniform in a square of START_FRACTION of the plate
                (hx, hy), f = self.plate_half_extent, self.START_FRACTION
                xy = np.stack([(-1.0 + 2.0 * d0) * f * hx, (-1.0 + 2.0 * d1) * f * hy], axis=1)
        else:
            xy = np.tile(position, (m, 1))
        if velocity is None:  # up to 0.1 m/s in a uniform direction
            velocity = polar(0.1 * draws[:, 1], 2 * math.pi * draws[:, 0])
        else:
            velocity = np.tile(velocity, (m, 1))
        return xy, velocity

    #: The ball starts within this fraction of the plate's half size of the centre (0.10 m on the 300 mm plate).
    START_FRACTION = 2.0 / 3.0
    #: ``start_distance`` may reach this fraction of the plate's smaller half size (0.12 m on the 300 mm plate).
    MAX_START_FRACTION = 0.8

    def _checked_start_distance(self, value: Sequence[float] | None) -> tuple[float, float] | None:
        """``start_distance`` as (low, high) m, checked: two finite numbers, 0 ≤ low ≤ high ≤
        :attr:`MAX_START_FRACTION` of the plate's smaller half size; :class:`~stewart_gym.errors.ConfigError`
        otherwise."""
        if value is None:
            return None
        reach = self.MAX_START_FRACTION * min(self.plate_half_extent)
        return number_range("start_distance", value, 0.0, reach, "m (on this plate)")

    #: The keys ``reset(options=…)`` accepts.
    RESET_OPTIONS = ("ball_position", "ball_velocity")
    #: m/s, the fastest ball speed a reset may ask for.
    MAX_RESET_SPEED = 2.0

    def _check_options(self, options: dict[str, Any] | None) -> dict[str, np.ndarray]:
        """Reset options as arrays, checked: known keys, two finite numbers each, a start on the plate.

        Raises :class:`~stewart_gym.errors.ConfigError` naming the option.
        """
        if options is None:
            return {}
        if not isinstance(options, dict):
            raise ConfigError(f"reset options must be a dict, got {type(options).__name__}")
        unknown = sorted(set(options) - set(self.RESET_OPTIONS))
        if unknown:
            raise ConfigError(f"unknown reset option(s) {unknown}; known: {list(self.RESET_OPTIONS)}")
        out = {}
        for key in self.RESET_OPTIONS:
            if key not in options:
                continue
            try:
                value = np.asarray(options[key], dtype=np.float64)
            except (TypeError, ValueError):
                raise ConfigError(f"reset option {key}: expected two numbers (x, y), got {options[key]!r}") from None
            if value.shape != (2,):
                raise ConfigError(f"reset option {key}: expected two numbers (x, y), got shape {value.shape}")
            if not np.all(np.isfinite(value)):
                raise ConfigError(f"reset option {key}: must be finite, got {value.tolist()}")
            out[key] = value
        # the ball starts with its whole contact patch on the plate: centre inside the plate's edge
        limit = np.array(self.plate_half_extent) - self.nominal_ball.radius
        if "ball_position" in out and np.any(np.abs(out["ball_position"]) > limit):
            raise ConfigError(f"reset option ball_position {out['ball_position'].tolist()} m is off the plate "
                              f"(|x| ≤ {limit[0]:.3f} m, |y| ≤ {limit[1]:.3f} m)")  # fmt: skip
        if "ball_velocity" in out and float(np.hypot(*out["ball_velocity"])) > self.MAX_RESET_SPEED:
            raise ConfigError(f"reset option ball_velocity {out['ball_velocity'].tolist()} m/s is faster than "
                              f"{self.MAX_RESET_SPEED} m/s")  # fmt: skip
        return out

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        mapped = self.begin_step(action)
        self.sim.step()
        return self.end_step(mapped)

    def begin_step(self, action: np.ndarray) -> Any:
        """The part of :meth:`step` before the physics: map the action, record it (for :meth:`__deepcopy__`), let
        the task act (a push) and send the pulses. Returns what :meth:`end_step` takes once the backend has
        advanced a control period. An action not of the action space's shape, not real numbers or not finite is a
        ``ValueError``, a step after :meth:`close` Gymnasium's ``ClosedEnvironmentError``, before anything moves."""
        if getattr(self.sim, "closed", False):
            raise ClosedEnvironmentError("this env is closed: reset() starts it again")
        if "params" not in self.__dict__:  # (gym.make's OrderEnforcing says so too; the unwrapped env alone did not)
            raise ResetNeeded("call reset() before step()")
        if type(action) is not np.ndarray or action.shape != self.action_space.shape or action.dtype.kind != "f":
            values = np.asarray(action)  # (the common case, a float array of the right shape, skips this)
            if values.shape != self.action_space.shape:
                raise ValueError(f"expected an action of shape {self.action_space.shape}, got shape {values.shape}")
            if values.dtype.kind not in "iuf":
                raise ValueError(f"an action must be real numbers, got an array of {values.dtype}")
        mapped = self.mapper(action)
        if self._episode is not None:
            self._episode.actions.append(np.array(action, copy=True))
        self.task.before_step(self.sim.time, self.sim)
        self.sim.command(mapped.pulses)
        return mapped

    def end_step(self, mapped: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        """The part of :meth:`step` after the physics: take ``mapped`` (:class:`~stewart_gym.actions.MappedAction`)
        as the step's action, sense, observe, reward, and the episode's end. (The batched vector env's copies do all
        this as arrays, :class:`~stewart_gym.envs.copies.CopySteps`, with the same results.)"""
        sim, task = self.sim, self.task
        self._pulses = mapped.pulses
        self._scaled = mapped.scaled
        self._unreachable += mapped.scaled
        if self.action_mode != "pulse":
            self._roll_pitch = (mapped.pose.item(3), mapped.pose.item(4))
        rate = 0.0  # the action rate: the mean squared change from the last action
        for v, p in zip(mapped.action, self._prev_action):
            rate += (v - p) * (v - p)
        rate /= len(mapped.action)
        self._prev_action = mapped.action
        t = sim.time
        x, y, z = sim.ball_position()
        if not (math.isfinite(x + y + z) and abs(z) < 1.0):  # NaN or a ball flung away: the physics blew up
            info = self._info(np.full(2, np.nan), (math.nan, math.nan), math.nan)
            info["physics_error"] = np.True_
            return self._last_obs.copy(), task.reward(2 * self.plate_half_extent[0], 0.0, True), True, False, info
        on_plate, touching = map(bool, ball_contact(x, y, z, self.plate_half_extent, self._plate_top, self._radius))
        self.sensor_model.record(t, (x, y), touching)
        target_xy, target_vel = task.target(t)
        obs = self.observer.observe(self.sensor_model.read(t), target_xy, target_vel, self._roll_pitch,
                                    mapped.action, now=t)  # fmt: skip
        self._last_obs = obs
        dist = distance(x - target_xy[0], y - target_xy[1])
        self._inside = self._inside + 1 if (on_plate and dist <= self.success_radius) else 0
        terminated = not on_plate
        reward = task.reward(dist, rate, terminated)
        info = self._info(np.array([x, y]), target_xy, dist)
        info["is_success"] = np.bool_(on_plate and self._inside >= self.success_steps)
        self._steps += 1
        return obs, reward, terminated, not terminated and self._steps >= self.episode_steps, info

    def render(self) -> np.ndarray | None:
        if getattr(self.sim, "marks_target", False):  # the target drawn on the plate, where the engine can
            self.sim.mark_target(self.task.target(self.sim.time)[0])
        return self.sim.render()

    def __deepcopy__(self, memo: dict) -> StewartBallEnv:
        """An independent env in the same state, mid-episode included: a new env made with the same arguments,
        its own engine, which replays this episode (the same random draws from the reset on, with the start box
        and the task as they were at the reset, then each action taken since), so that from here both step alike,
        to the last bit. The copy then takes this env's task, start box (:attr:`START_FRACTION`) and generator as
        they are now: settings a curriculum changed, and draws taken from :attr:`np_random` by others, carry over.
        Before the first reset: a new env with this env's task, start box and generator.

        An env made on a backend object (``backend=`` a simulator, as each copy of the batched vector env is) has no
        engine of its own to copy: a ``TypeError`` says so."""
        if self._engine is None:
            raise TypeError(f"copy.deepcopy: this env steps the backend object it was given ({type(self.sim).__name__}), "
                            "which a copy would share; make the copy with gym.make(id, backend=...) by name")  # fmt: skip
        replay = self._episode
        twin = type(self)(*self._ezpickle_args, **self._ezpickle_kwargs)
        memo[id(self)] = twin
        try:
            seed = self.np_random_seed  # (-1 where the generator was given, not seeded)
            if seed >= 0:  # the copy says the same seed: its generator seeded so, then set to the state below
                gym.Env.reset(twin, seed=seed)
            else:
                twin.np_random = np.random.Generator(type(self.np_random.bit_generator)())
            shared = self._own_parts(twin)  # a task that holds the env, its engine or its generator: the copy's
            if replay is not None:
                twin.np_random.bit_generator.state = replay.draws
                twin.START_FRACTION = replay.start_fraction
                twin.task = self._copied_task(replay.task, shared)
                twin.reset(options=copy.deepcopy(replay.options))
                for action in replay.actions:
                    twin.step(action)
            twin.np_random.bit_generator.state = self.np_random.bit_generator.state  # in place: the sensor's too
            twin.task = self._copied_task(self.task, shared)
            if "START_FRACTION" in vars(self):
                twin.START_FRACTION = self.START_FRACTION
            else:
                vars(twin).pop("START_FRACTION", None)
        except BaseException:
            twin.close()
            raise
        return twin

    def close(self) -> None:
        """Release the engine; :meth:`reset` starts it again (a backend object given by the caller stays closed)."""
        sim = getattr(self, "sim", None)
        if sim is not None:
            sim.close()

    def _reopen(self) -> None:
        """A closed engine made again as it was built (the episode's physics come with the reset)."""
        if self._engine is None:
            raise RuntimeError("this env's backend was given as an object and has been closed; make the env anew")
        backend, geometry, physics_hz, control_hz, render_mode = self._engine
        self._closed_sim = self.sim  # a task may still hold it from the last episode (:meth:`_own_parts`)
        self.sim = make_backend(backend, geometry, physics_hz=physics_hz, control_hz=control_hz, ball=True,
                                ball_spec=self.nominal_ball, servo_spec=self.nominal_servo,
                                render_mode=render_mode)  # fmt: skip

    # ------------------------------------------------------------- helpers
    def _reset_episode_state(self) -> None:
        self._steps = 0
        self._prev_action: tuple[float, ...] = (0.0,) * self.mapper.size
        self._roll_pitch = (0.0, 0.0)
        self._inside = 0
        self._unreachable = 0
        self._scaled = False
        self._pulses = self.sim.calibration.neutral_us.copy()

    def _observe(self, t: float) -> np.ndarray:
        target_xy, target_vel = self.task.target(t)
        return self.observer.observe(self.sensor_model.read(t), target_xy, target_vel, self._roll_pitch,
                                     self._prev_action, now=t)  # fmt: skip

    def _info(self, xy: np.ndarray, target_xy: tuple[float, float], dist: float) -> dict[str, Any]:
        return {
            "is_success": np.False_,
            "distance_mm": np.float64(dist * 1e3),
            "ball_xy_m": xy,
            "target_xy_m": np.array(target_xy, dtype=np.float64),
            "pulse_widths_us": self._pulses,
            "commanded_tilt_rad": np.array(self._roll_pitch),
            "action_scaled": np.bool_(self._scaled),
            "unreachable_count": np.int64(self._unreachable),
            "physics_error": np.False_,
            **self.task.info(),
        }


def distance(dx: float, dy: float) -> float:
    """m, the length of (dx, dy) as ``sqrt(dx² + dy²)``: the same bits as NumPy's on arrays (the batched vector env's
    copies, :class:`~stewart_gym.envs.copies.CopySteps`), which ``math.hypot`` is not."""
    return math.sqrt(dx * dx + dy * dy)


def env_keywords(task: str | Task = "balance") -> set[str]:
    """The keywords ``gym.make(id, ...)`` takes for an env of ``task``: :class:`StewartBallEnv`'s own and its task's."""
    import inspect

    own = set(inspect.signature(StewartBallEnv.__init__).parameters) - {"self", "task", "task_kwargs"}
    return own | (task_keywords(task) if isinstance(task, str) else set())


def _tables_into_docstring() -> None:
    """The action and observation tables of the docstring, generated from the code that defines them."""
    from stewart_gym.actions import action_table
    from stewart_gym.sensing import observation_table

    def indent(table: str) -> str:
        return "\n".join("    " + line for line in table.splitlines()).lstrip()

    doc = StewartBallEnv.__doc__ or ""
    StewartBallEnv.__doc__ = doc.replace("ACTION_TABLE", indent(action_table())).replace(
        "OBSERVATION_TABLE", indent(observation_table()))  # fmt: skip


_tables_into_docstring()
