"""MuJoCo simulation of a Stewart platform, rotary or linear: the second, independent physics backend.

The model comes from :func:`~stewart_gym.sim.mjcf.mechanism_mjcf` (closed loops as
``connect`` equality constraints). The servos are driven exactly as in PyBullet:
pulses go through the same :class:`~stewart_gym.sim.HobbyServos` front end (lag,
dead band, quantisation, trim error) to target angles; each physics step a
velocity actuator is commanded ``clip(k·(target − q), ±max_speed)`` with at most the
stall torque, which is what PyBullet's position motor does (``k`` = the servo's
``position_gain`` × 150 /s, the gain of PyBullet's motor at the envs' 150 Hz).

Implements :class:`~stewart_gym.sim.PhysicsBackend`; ``tests/sim/test_backend_contract.py``
runs the same checks on both engines.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from stewart_gym.calibration import ServoCalibration
from stewart_gym.constants import GRAVITY
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.sim.backend import BallSpec, PlateLoad, SimulatorBase
from stewart_gym.sim.mjcf import MujocoPhysics, ball_friction, mechanism_mjcf
from stewart_gym.sim.servo_model import ServoSpec
from stewart_gym.sim.urdf import MechanismSpec

__all__ = ["MOTOR_REFERENCE_HZ", "MujocoSim", "check_rendering"]

#: Hz: the servo loop gain is ``position_gain`` × this (PyBullet's position motor at the envs' 150 Hz physics).
MOTOR_REFERENCE_HZ = 150.0


def _mujoco():  # noqa: ANN202 - the module
    try:
        import mujoco
    except ImportError:  # pragma: no cover - depends on the install
        from stewart_gym.errors import ConfigError

        raise ConfigError("the MuJoCo backend needs the mujoco package: pip install 'stewart_gym[mujoco]'") from None
    return mujoco


#: Why MuJoCo could not render in this process (None: it has not failed). A second try after a failed start of its
#: OpenGL context can abort the whole process (GLFW's initialisation re-entered), so a failure is final.
_render_failure: str | None = None


def _renderer(mj: Any, model: Any, height: int, width: int) -> Any:
    """A MuJoCo offscreen renderer, or :class:`ConfigError` in one line where OpenGL cannot start (then at once on
    every later call in this process: it is not tried again)."""
    global _render_failure
    from stewart_gym.errors import ConfigError

    if _render_failure is None:
        import warnings

        try:
            with warnings.catch_warnings():  # GLFW warns before it fails; the failure is reported in one line
                warnings.simplefilter("ignore")
                return mj.Renderer(model, height, width)
        except Exception as exc:  # no OpenGL context on this machine (the error's own text may fail to print)
            _render_failure = f"{type(exc).__name__} from OpenGL"
    raise ConfigError(f"MuJoCo cannot render on this machine ({_render_failure}): set MUJOCO_GL=egl (a GPU) or "
                      "MUJOCO_GL=osmesa (software, libOSMesa), or use the pybullet backend for images")  # fmt: skip


def check_rendering() -> None:
    """Raise :class:`~stewart_gym.errors.ConfigError` now if MuJoCo cannot render here (before long work)."""
    mj = _mujoco()
    model = mj.MjModel.from_xml_string("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>")
    _renderer(mj, model, 8, 8).close()


def _quat_matrix(q: Sequence[float]) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


class MujocoSim(SimulatorBase):
    """A servo (or RC linear actuator) Stewart platform in MuJoCo, commanded in pulse widths.

    Args mirror :class:`~stewart_gym.sim.StewartSim`: ``geometry`` (rotary or
    linear), ``calibration`` (default for the geometry), ``physics_hz`` (default
    ``physics.physics_hz``; a multiple of ``control_hz``), ``control_hz``,
    ``ball``, ``ball_spec``, ``servo_spec``, ``mechanism``, ``physics``
    (:class:`~stewart_gym.sim.mjcf.MujocoPhysics`), ``render_mode``
    (``"rgb_array"``: offscreen OpenGL, see :meth:`render`) and ``render_size``.
    """

    def __init__(
        self,
        geometry: PlatformGeometry | str = "servo-hexapod",
        calibration: ServoCalibration | None = None,
        physics_hz: int | None = None,
        control_hz: int = 50,
        ball: bool = False,
        *,
        ball_spec: BallSpec | None = None,
        servo_spec: ServoSpec | None = None,
        mechanism: MechanismSpec | None = None,
        physics: MujocoPhysics | None = None,
        render_mode: Literal["rgb_array"] | None = None,
        render_size: tuple[int, int] = (480, 360),
    ) -> None:
        mj = _mujoco()
        physics = physics or MujocoPhysics()
        physics_hz = int(physics_hz or physics.physics_hz)
        self._setup(geometry, calibration, physics_hz, control_hz, ball, ball_spec, servo_spec, mechanism, render_mode,
                    render_size, ("rgb_array",))  # fmt: skip
        self.physics = MujocoPhysics(**{**vars(physics), "physics_hz": physics_hz})
        self._mj = mj
        # the warnings MuJoCo gives where it finds the simulation unstable, and then resets its state
        self._instabilities = tuple(int(kind) for kind in (mj.mjtWarning.mjWARN_BADQPOS, mj.mjtWarning.mjWARN_BADQVEL,
                                                             mj.mjtWarning.mjWARN_BADQACC))  # fmt: skip
        self._plate_friction = 0.6
        self.xml = mechanism_mjcf(self.geometry, self.mechanism, self.servo_spec, self.physics,
                                  ball=self.ball_spec if self.has_ball else None,
                                  plate_friction=self._plate_friction)  # fmt: skip
        self.model = mj.MjModel.from_xml_string(self.xml)
        self.data = mj.MjData(self.model)
        m = self.model
        joint = lambda name: mj.mj_name2id(m, mj.mjtObj.mjOBJ_JOINT, name)  # noqa: E731
        servo_joints = [joint(f"servo_{i}") for i in range(6)]
        self._servo_q = np.array([m.jnt_qposadr[j] for j in servo_joints])
        self._servo_v = np.array([m.jnt_dofadr[j] for j in servo_joints])
        self._plate_body = mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, "plate")
        self._plate_q = int(m.jnt_qposadr[joint("plate")])
        self._rod_top_sites = [mj.mj_name2id(m, mj.mjtObj.mjOBJ_SITE, f"rod_{i}_top") for i in range(6)]
        self._anchor_sites = [mj.mj_name2id(m, mj.mjtObj.mjOBJ_SITE, f"anchor_{i}") for i in range(6)]
        if self.has_ball:
            self._ball_body = mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, "ball")
            self._ball_geom = mj.mj_name2id(m, mj.mjtObj.mjOBJ_GEOM, "ball")
            self._ball_q = int(m.jnt_qposadr[joint("ball")])
            self._ball_v = int(m.jnt_dofadr[joint("ball")])
        self._home = inverse_kinematics(self.geometry, np.zeros(6)).actuators
        self._gain = self.servo_spec.position_gain * MOTOR_REFERENCE_HZ
        self._target = np.zeros(6)
        self._renderer = None
        self.reset()

    # ------------------------------------------------------------ commanding
    def _apply_targets(self, targets: list[float]) -> None:
        self._target = np.asarray(targets) - self._home

    def step(self) -> None:
        """Advance one control period (``substeps`` physics steps)."""
        mj, m, d = self._mj, self.model, self.data
        update, q_adr, gain, ctrl, qpos = self._servos.update, self._servo_q, self._gain, d.ctrl, d.qpos
        if self._plate_load is not None:
            d.xfrc_applied[self._plate_body] = self._plate_load_wrench()
        for _ in range(self.substeps):
            targets = update(self._step_count)
            if targets is not None:
                self._apply_targets(targets)
            # velocity command k·(target − q); the actuators' ctrlrange clips it to ±max_speed
            np.multiply(np.subtract(self._target, qpos[q_adr], out=ctrl), gain, out=ctrl)
            mj.mj_step(m, d)
            self._step_count += 1

    def _plate_load_wrench(self) -> np.ndarray:
        """The extra mass's weight as a force and torque at the plate's centre of mass (world frame)."""
        mass, offset = self._plate_load  # type: ignore[misc]
        origin, rot = self._plate_frame()
        fz = -mass * GRAVITY
        ax, ay, _ = (origin + rot @ offset - self.data.xipos[self._plate_body]).tolist()
        return np.array([0.0, 0.0, fz, ay * fz, -ax * fz, 0.0])  # torque = arm × (0, 0, fz)

    def reset(self, *, servo_spec: ServoSpec | None = None, ball_spec: BallSpec | None = None,
              plate_friction: float | None = None, plate_load: PlateLoad | None = None) -> None:  # fmt: skip
        """Home pose (every joint at its home value), servos holding neutral, ball at rest at the plate centre."""
        mj, m, d = self._mj, self.model, self.data
        if servo_spec is not None:
            self._new_servo_model(servo_spec)
            self._gain = servo_spec.position_gain * MOTOR_REFERENCE_HZ
            m.actuator_forcerange[:] = (-servo_spec.stall_torque, servo_spec.stall_torque)
            m.actuator_ctrlrange[:] = (-servo_spec.max_speed, servo_spec.max_speed)
            m.actuator_gainprm[:, 0] = servo_spec.stall_torque / (self.physics.servo_slip * servo_spec.max_speed)
            m.actuator_biasprm[:, 2] = -m.actuator_gainprm[:, 0]
        if plate_friction is not None:
            self._plate_friction = float(plate_friction)
        if self.has_ball:
            if ball_spec is not None:
                self.ball_spec = ball_spec
            b = self.ball_spec
            m.geom_size[self._ball_geom, 0] = b.radius
            m.geom_rbound[self._ball_geom] = b.radius
            m.body_mass[self._ball_body] = b.mass
            m.body_inertia[self._ball_body] = b.inertia
            m.geom_friction[self._ball_geom] = ball_friction(b, self._plate_friction)
            if ball_spec is not None:
                mj.mj_setConst(m, d)
        mj.mj_resetData(m, d)
        d.xfrc_applied[:] = 0.0
        self._step_count = 0
        self.set_plate_load(plate_load)
        self._apply_targets(self._servos.reset())
        if self.has_ball:
            d.qpos[self._ball_q + 2] = self.geometry.home_height + self.plate_top + self.ball_spec.radius
        mj.mj_forward(m, d)

    # ------------------------------------------------------- disturbances
    def push_ball(self, impulse_xy: tuple[float, float]) -> None:
        """Give the ball an impulse (N·s) along the plate (plate frame); it keeps rolling."""
        self._require_ball()
        _, rot = self._plate_frame()
        dv, dw = self._push_change(impulse_xy, rot)
        self._set_ball_velocity(self.data.qvel[self._ball_v:self._ball_v + 3] + dv, self._ball_omega() + dw)

    def set_plate_load(self, load: PlateLoad | None) -> None:
        """Put an extra mass on the plate (or take it off) from the next :meth:`step` on."""
        super().set_plate_load(load)
        if load is None:
            self.data.xfrc_applied[self._plate_body] = 0.0

    # ------------------------------------------------------------ state
    def _plate_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """Platform frame in the world, from the current state: origin (3,) m and rotation (3, 3)."""
        q = self.data.qpos[self._plate_q:self._plate_q + 7]
        return q[:3].copy(), _quat_matrix(q[3:7])

    def servo_angles(self) -> np.ndarray:
        """(6,) rad: the horn angles α; leg lengths (m) on a linear platform."""
        return self.data.qpos[self._servo_q] + self._home

    def servo_velocities(self) -> np.ndarray:
        """(6,) rad/s (m/s linear)."""
        return self.data.qvel[self._servo_v].copy()

    def constraint_error(self) -> float:
        """m: the largest gap between a rod top and its plate anchor (loop-closure error)."""
        self._mj.mj_kinematics(self.model, self.data)
        x = self.data.site_xpos
        return float(np.max(np.linalg.norm(x[self._rod_top_sites] - x[self._anchor_sites], axis=1)))

    # --------------------------------------------------------------- ball
    def _ball_omega(self) -> np.ndarray:
        """Ball angular velocity, world frame (a free joint's is in the body frame)."""
        q = self.data.qpos[self._ball_q + 3:self._ball_q + 7]
        return _quat_matrix(q) @ self.data.qvel[self._ball_v + 3:self._ball_v + 6]

    def _set_ball_velocity(self, linear: np.ndarray, omega_world: np.ndarray) -> None:
        q = self.data.qpos[self._ball_q + 3:self._ball_q + 7]
        self.data.qvel[self._ball_v:self._ball_v + 3] = linear
        self.data.qvel[self._ball_v + 3:self._ball_v + 6] = _quat_matrix(q).T @ omega_world

    def place_ball(self, xy: np.ndarray, velocity_xy: Sequence[float] = (0.0, 0.0)) -> None:
        """Put the ball on the plate at ``xy`` (m, plate frame) rolling with ``velocity_xy`` (m/s, plate frame)."""
        self._require_ball()
        origin, rot = self._plate_frame()
        local = np.array([xy[0], xy[1], self.plate_top + self.ball_spec.radius])
        self.data.qpos[self._ball_q:self._ball_q + 3] = origin + rot @ local
        self.data.qpos[self._ball_q + 3:self._ball_q + 7] = (1.0, 0.0, 0.0, 0.0)
        self._set_ball_velocity(*self._rolling_velocity(velocity_xy, rot))

    def ball_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ball position and velocity in the platform frame: ((3,) m, (3,) m/s)."""
        self._require_ball()
        _, rot = self._plate_frame()
        return np.array(self.ball_position()), self.data.qvel[self._ball_v:self._ball_v + 3] @ rot

    def blew_up(self) -> bool:
        """Whether MuJoCo found the simulation unstable since the last reset (a NaN, infinite or huge position,
        velocity or acceleration): it then starts its state again from the model's, which no longer follows the
        episode."""
        counts = self.data.warning
        return any(counts[kind].number for kind in self._instabilities)

    def ball_position(self) -> tuple[float, float, float]:
        """Ball centre (x, y, z) in the platform frame, m; NaN where the simulation blew up (:meth:`blew_up`), as
        PyBullet's own position is then."""
        self._require_ball()
        if self.blew_up():
            return (math.nan, math.nan, math.nan)
        origin, rot = self._plate_frame()
        p = (self.data.qpos[self._ball_q:self._ball_q + 3] - origin) @ rot
        return (float(p[0]), float(p[1]), float(p[2]))

    def ball_world_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ball position (3,) m and velocity (3,) m/s in the world (base) frame."""
        self._require_ball()
        return (self.data.qpos[self._ball_q:self._ball_q + 3].copy(),
                self.data.qvel[self._ball_v:self._ball_v + 3].copy())  # fmt: skip

    # -------------------------------------------------------------- render
    def render(self) -> np.ndarray | None:
        """An RGB frame (height, width, 3) uint8 for ``rgb_array``, from the model's ``view`` camera.

        MuJoCo renders with OpenGL: headless machines need ``MUJOCO_GL=egl`` (a
        GPU driver) or ``MUJOCO_GL=osmesa`` (software); without one, this raises
        a one-line error naming them.
        """
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            width, height = self.render_size
            self._renderer = _renderer(self._mj, self.model, height, width)
        self._mj.mj_forward(self.model, self.data)
        self._renderer.update_scene(self.data, camera="view")
        return self._renderer.render()

    # ------------------------------------------------------------ lifecycle
    def close(self) -> None:
        """Release the renderer; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


