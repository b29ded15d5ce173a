"""PyBullet simulation of a servo-driven Stewart platform with closed kinematic loops.

Structure: the URDF tree base → horns → (universal joint) → rods is loaded as
six fixed-base bodies, one per leg (the base is fixed, so this is the same
mechanism and a cheaper solve); the plate is another body; six point-to-point
constraints join each rod top to its plate anchor. Servos are position motors
on the horn joints, commanded in pulse widths through
:class:`~stewart_gym.sim.servo_model.HobbyServos`. An optional ball rolls on the plate.

Rates are explicit: ``physics_hz`` must be a multiple of ``control_hz``; one
:meth:`StewartSim.step` advances one control period (one servo frame at the
default 50 Hz). Every PyBullet call goes through this instance's own client, so
several simulators can live in one process or in worker processes. The world is
built once; :meth:`StewartSim.reset` restores a saved state.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Literal

import numpy as np

from stewart_gym.calibration import ServoCalibration
from stewart_gym.camera import CameraSpec
from stewart_gym.constants import GRAVITY
from stewart_gym.geometry import PlatformGeometry
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.sim.backend import BallSpec, PlateLoad, SimulatorBase
from stewart_gym.sim.servo_model import ServoSpec
from stewart_gym.sim.urdf import MechanismSpec, mechanism_urdf, plate_urdf
from stewart_gym.vision import MarkerLayout

__all__ = ["MARKER_FACE_HEIGHT", "PhysicsSpec", "StewartSim"]

#: m: how far above the plate's top the rendered markers' black cells lie (their white quiet zones half as far):
#: thin boxes, apart enough not to flicker. What ``sysid --marker-height-mm`` is told for the virtual board.
MARKER_FACE_HEIGHT = 0.0008



@dataclass(frozen=True)
class PhysicsSpec:
    """Constraint-solver settings, chosen by measurement (``bench/bench_sim.py --solvers``).

    With the exact Dantzig LCP solver the loop gap comes only from integrating
    each step, so it shrinks with dt² and with a firmer ``erp``; the iterative
    solver leaves loops open by ~1 mm and is slower.

    Attributes:
        solver: ``"dantzig"`` (exact LCP) or ``"si"`` (PyBullet's default
            sequential impulse, iterative).
        solver_iterations: iterations of the iterative solver.
        erp: error reduction of joints and constraints per step (PyBullet's
            global ``erp``; a multibody constraint ignores its own). Contacts
            keep PyBullet's default.
        constraint_max_force: N, the most a loop constraint may pull.
        plate_friction: lateral friction of the plate surface.
    """

    solver: Literal["dantzig", "si"] = "dantzig"
    solver_iterations: int = 50
    erp: float = 0.9
    constraint_max_force: float = 1000.0
    plate_friction: float = 0.6


@contextlib.contextmanager
def _quiet_fd(fd: int) -> Iterator[None]:
    """Send file descriptor ``fd`` (1 stdout, 2 stderr) to /dev/null for the block (C-level prints included)."""
    (sys.stdout if fd == 1 else sys.stderr).flush()
    try:
        saved = os.dup(fd)
    except OSError:  # no usable descriptor: nothing to protect
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


# Importing PyBullet prints its build time on stderr: on every command, and above a mistake's `error: …` line.
with _quiet_fd(2):
    import pybullet as pb
    from pybullet_utils.bullet_client import BulletClient


class StewartSim(SimulatorBase):
    """A servo Stewart platform in PyBullet, commanded in pulse widths. It renders camera images
    (:meth:`camera_image`, :attr:`renders_camera`).

    Args:
        geometry: Preset name, TOML path or :class:`PlatformGeometry` (rotary).
        calibration: Pulse ↔ angle mapping shared with hardware; default
            :meth:`ServoCalibration.default` of the geometry.
        physics_hz: Physics rate, a multiple of ``control_hz``. The default 200 Hz
            (4 steps per servo frame) keeps loops closed within 0.07 mm during
            full-speed moves; see ``bench/bench_sim.py --solvers``.
        control_hz: Rate of :meth:`step` (servo frames).
        ball: Add a ball on the plate.
        ball_spec: The ball (engine-neutral :class:`~stewart_gym.sim.BallSpec`).
        servo_spec: The hobby servos' behaviour.
        mechanism: Masses and sizes of the parts.
        physics: Solver settings.
        render_mode: ``None``, ``"rgb_array"`` (headless TinyRenderer) or ``"human"`` (GUI).
        render_size: (width, height) of ``rgb_array`` frames.
    """

    def __init__(
        self,
        geometry: PlatformGeometry | str = "servo-hexapod",
        calibration: ServoCalibration | None = None,
        physics_hz: int = 200,
        control_hz: int = 50,
        ball: bool = False,
        *,
        ball_spec: BallSpec | None = None,
        servo_spec: ServoSpec | None = None,
        mechanism: MechanismSpec | None = None,
        physics: PhysicsSpec | None = None,
        render_mode: Literal["rgb_array", "human"] | None = None,
        render_size: tuple[int, int] = (480, 360),
    ) -> None:
        self._setup(geometry, calibration, physics_hz, control_hz, ball, ball_spec, servo_spec, mechanism, render_mode,
                    render_size, ("rgb_array", "human"))  # fmt: skip
        self.physics = physics or PhysicsSpec()
        self._home_alpha = inverse_kinematics(self.geometry, np.zeros(6)).actuators
        self._home_list: list[float] = self._home_alpha.tolist()
        self._tmp = Path(tempfile.mkdtemp(prefix="stewart_gym_"))
        try:
            self._build()
        except Exception:
            self.close()
            raise

    # ------------------------------------------------------------- building
    renders_camera = True

    def _build(self) -> None:
        if self.render_mode == "human" and sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
            # PyBullet's GUI ends the whole process when it cannot open a window.
            raise RuntimeError("render_mode='human' needs a display (DISPLAY is not set); use 'rgb_array' headless")
        with _quiet_fd(1):  # PyBullet's C code prints banners on stdout; keep it clean (e.g. for --json)
            c = BulletClient(connection_mode=pb.GUI if self.render_mode == "human" else pb.DIRECT)
        self._client = c
        # Hot-path calls bound once: BulletClient builds a new partial on every attribute access.
        cid = c._client
        self._pb_step = partial(pb.stepSimulation, physicsClientId=cid)
        self._cid = cid
        self._pb_base_pose = partial(pb.getBasePositionAndOrientation, physicsClientId=cid)
        self._pb_base_velocity = partial(pb.getBaseVelocity, physicsClientId=cid)
        self._pb_force = partial(pb.applyExternalForce, physicsClientId=cid)
        self._frame: tuple[np.ndarray, np.ndarray] | None = None
        c.setGravity(0, 0, -GRAVITY)
        c.setTimeStep(1.0 / self.physics_hz)
        solver = pb.CONSTRAINT_SOLVER_LCP_DANTZIG if self.physics.solver == "dantzig" else pb.CONSTRAINT_SOLVER_LCP_SI
        with _quiet_fd(1):
            c.setPhysicsEngineParameter(
                constraintSolverType=solver, numSolverIterations=self.physics.solver_iterations,
                erp=self.physics.erp, deterministicOverlappingPairs=1,
            )  # fmt: skip
        geo = self.geometry
        flags = pb.URDF_USE_INERTIA_FROM_FILE
        # One fixed-base body per leg (base → horn → universal joint → rod), from the same generator as the
        # whole-tree URDF: with the base fixed the legs interact only through the plate, so the motion is
        # the same, and each solver row costs O(3 links) instead of O(18): measured with the ball at 200 Hz,
        # 3,580 control steps/s as one tree, 5,300 as six legs, the same worst loop gap (0.0695 mm).
        self.legs: list[int] = []
        for i in range(6):
            path = self._tmp / f"leg_{i}.urdf"
            text = mechanism_urdf(geo, self.mechanism, self.servo_spec, legs=[i], base_plate=i == 0)
            path.write_text(text, encoding="utf-8")
            self.legs.append(c.loadURDF(str(path), useFixedBase=True, flags=flags))
        plate_path = self._tmp / "plate.urdf"
        plate_path.write_text(plate_urdf(geo, self.mechanism), encoding="utf-8")
        self.plate = c.loadURDF(str(plate_path), basePosition=geo.home_position.tolist(), flags=flags)
        # joint indices within each leg body (a joint's index is its child link's)
        names = {c.getJointInfo(self.legs[0], j)[1].decode(): j for j in range(c.getNumJoints(self.legs[0]))}
        rotary = geo.is_rotary  # a rod's top: at (0, 0, s) of the rod link (rotary) or the top link's origin (linear)
        self._servo_joint, self._rod_link = names["servo_0"], names["rod_0_u2" if rotary else "servo_0"]
        self._rod_top = geo.rod_length if rotary else 0.0
        passive = [names["rod_0_u1"], names["rod_0_u2"]]
        for leg in self.legs:
            c.setJointMotorControlArray(leg, passive, pb.VELOCITY_CONTROL, forces=[0.0] * len(passive))
            # Nothing in the mechanism collides (with itself, the plate or the ball).
            for link in range(-1, c.getNumJoints(leg)):
                c.setCollisionFilterGroupMask(leg, link, 0, 0)
                c.changeDynamics(leg, link, linearDamping=0.0, angularDamping=0.0)
        c.changeDynamics(self.plate, -1, lateralFriction=self.physics.plate_friction, linearDamping=0.0,
                         angularDamping=0.0)  # fmt: skip
        self._plate_com = np.array(c.getDynamicsInfo(self.plate, -1)[3])  # inertial origin in the plate frame
        self._plate_com_list: list[float] = self._plate_com.tolist()
        self._constraints = []
        s = self._rod_top
        for i, leg in enumerate(self.legs):
            rod_com = np.array(c.getDynamicsInfo(leg, self._rod_link)[3])
            cid = c.createConstraint(
                leg, self._rod_link, self.plate, -1, pb.JOINT_POINT2POINT, [0, 0, 0],
                parentFramePosition=(np.array([0, 0, s]) - rod_com).tolist(),
                childFramePosition=(geo.platform_anchors[i] - self._plate_com).tolist(),
            )  # fmt: skip
            c.changeConstraint(cid, maxForce=self.physics.constraint_max_force)
            self._constraints.append(cid)
        self._apply_targets(self._servos.reset())
        self._state = c.saveState()  # without the ball: it is rebuilt on reset, so its size can change
        self._ball_shapes: dict[float, tuple[int, int]] = {}
        self._plate_load: tuple[float, np.ndarray] | None = None
        self.ball = self._make_ball() if self.has_ball else None
        self._marker_body: int | None = None
        self._marker_layout: MarkerLayout | None = None
        self._target_body: int | None = None

    def _make_ball(self) -> int:
        """Create the ball resting at the plate centre (collision shapes are cached per radius)."""
        c, spec = self._client, self.ball_spec
        shapes = self._ball_shapes.get(spec.radius)
        if shapes is None:
            shapes = (c.createCollisionShape(pb.GEOM_SPHERE, radius=spec.radius),
                      c.createVisualShape(pb.GEOM_SPHERE, radius=spec.radius, rgbaColor=[0.85, 0.85, 0.9, 1]))  # fmt: skip
            self._ball_shapes[spec.radius] = shapes
        ball = c.createMultiBody(spec.mass, shapes[0], shapes[1], basePosition=self._plate_point([0, 0]).tolist())
        c.changeDynamics(ball, -1, localInertiaDiagonal=[spec.inertia] * 3, lateralFriction=spec.lateral_friction,
                         rollingFriction=spec.rolling_friction, spinningFriction=spec.spinning_friction,
                         restitution=spec.restitution, linearDamping=0.0, angularDamping=0.0)  # fmt: skip
        return ball

    # ------------------------------------------------------------ commanding
    def step(self) -> None:
        """Advance one control period (``substeps`` physics steps)."""
        step, update = self._pb_step, self._servos.update
        load = self._plate_load_force() if self._plate_load is not None else None
        for _ in range(self.substeps):
            targets = update(self._step_count)
            if targets is not None:
                self._apply_targets(targets)
            if load is not None:  # PyBullet clears external forces after every physics step
                self._pb_force(self.plate, -1, load[0], load[1], pb.WORLD_FRAME)
            step()
            self._step_count += 1
        self._frame = None

    def _plate_load_force(self) -> tuple[list[float], list[float]]:
        """The extra plate mass's weight (N) and the world point (m) it acts at, for this control period.

        The point follows the plate once per control period (the plate turns by
        a few hundredths of a radian in that time at most).
        """
        mass, offset = self._plate_load  # type: ignore[misc]
        origin, rot = self._plate_frame()
        return [0.0, 0.0, -mass * GRAVITY], (origin + rot @ offset).tolist()

    def _apply_targets(self, angles: list[float]) -> None:
        """Servo motors aim at ``angles`` (6,) rad, at most the stall torque and the servo speed."""
        spec, joint, cid = self.servo_spec, self._servo_joint, self._cid
        torque, kp, kd, speed = spec.stall_torque, spec.position_gain, spec.velocity_gain, spec.max_speed
        for leg, angle, home in zip(self.legs, angles, self._home_list):
            # positional arguments (bodyUniqueId, jointIndex, controlMode, targetPosition, targetVelocity, force,
            # positionGain, velocityGain, maxVelocity, physicsClientId): keywords cost twice as much to parse
            pb.setJointMotorControl2(leg, joint, pb.POSITION_CONTROL, angle - home, 0.0, torque, kp, kd, speed, cid)

    def reset(self, *, servo_spec: ServoSpec | None = None, ball_spec: BallSpec | None = None,
              plate_friction: float | None = None, plate_load: PlateLoad | None = None) -> None:  # fmt: skip
        """Restore the home state saved at build time (no reloading); servos hold neutral pulses.

        Optional per-episode changes (domain randomisation): a new ``servo_spec``
        or ``ball_spec`` (the ball is rebuilt, at rest at the plate centre), the
        plate's ``plate_friction``, and ``plate_load`` = (mass kg, (3,) offset m
        in the platform frame), an extra mass on the plate applied as its weight.
        """
        c = self._client
        if self.ball is not None:
            c.removeBody(self.ball)
        if self._marker_body is not None:  # restoreState needs the bodies of the saved state only
            c.removeBody(self._marker_body)
            self._marker_body = None
        if self._target_body is not None:
            c.removeBody(self._target_body)
            self._target_body = None
        c.restoreState(self._state)
        self._frame = None
        self._step_count = 0
        if servo_spec is not None:
            self._new_servo_model(servo_spec)
        if plate_friction is not None:
            c.changeDynamics(self.plate, -1, lateralFriction=float(plate_friction))
        self.set_plate_load(plate_load)
        if self.has_ball:
            if ball_spec is not None:
                self.ball_spec = ball_spec
            self.ball = self._make_ball()
        self._apply_targets(self._servos.reset())

    # ------------------------------------------------------- disturbances
    def push_ball(self, impulse_xy: tuple[float, float]) -> None:
        """Give the ball an impulse (N·s) along the plate, in the plate frame: a sudden change of its velocity."""
        ball, c = self._ball_body(), self._client
        _, rot = self._plate_frame()
        lin, ang = self._pb_base_velocity(ball)
        dv, dw = self._push_change(impulse_xy, rot)
        c.resetBaseVelocity(ball, (np.array(lin) + dv).tolist(), (np.array(ang) + dw).tolist())

    # ------------------------------------------------------------ state
    def _plate_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """Platform frame in the world: origin (3,) m and rotation (3, 3); cached until the next step."""
        if self._frame is None:
            pos, orn = self._pb_base_pose(self.plate)
            rot = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
            self._frame = (np.array(pos) - rot @ self._plate_com, rot)
        return self._frame

    def servo_angles(self) -> np.ndarray:
        """(6,) rad: the horn angles α (from the horizontal, as in eq. 9); leg lengths (m) on a linear platform."""
        return np.array([s[0] for s in self._servo_states()]) + self._home_alpha

    def servo_velocities(self) -> np.ndarray:
        """(6,) rad/s."""
        return np.array([s[1] for s in self._servo_states()])

    def _servo_states(self) -> list[tuple]:
        get, joint = self._client.getJointState, self._servo_joint
        return [get(leg, joint) for leg in self.legs]

    def constraint_error(self) -> float:
        """m: the largest gap between a rod top and its plate anchor (loop-closure error)."""
        c, s = self._client, self._rod_top
        states = [c.getLinkState(leg, self._rod_link, computeForwardKinematics=True) for leg in self.legs]
        tops = np.array([
            np.array(st[4]) + np.array(c.getMatrixFromQuaternion(st[5])).reshape(3, 3)[:, 2] * s for st in states
        ])  # fmt: skip
        origin, rot = self._plate_frame()
        anchors = origin + self.geometry.platform_anchors @ rot.T
        return float(np.max(np.linalg.norm(tops - anchors, axis=1)))

    # --------------------------------------------------------------- ball
    def _ball_body(self) -> int:
        """The ball's PyBullet body (a ``RuntimeError`` without one)."""
        self._require_ball()
        assert self.ball is not None
        return self.ball

    def _plate_point(self, xy: np.ndarray, lift: float = 0.0) -> np.ndarray:
        """World position of a ball resting at plate coordinates ``xy`` (m) on the top surface."""
        origin, rot = self._plate_frame()
        local = np.array([xy[0], xy[1], self.mechanism.plate_top + self.ball_spec.radius + lift])
        return origin + rot @ local

    #: whether :meth:`mark_target` draws the target in rendered frames (an optional capability)
    marks_target = True

    def mark_target(self, xy: Sequence[float]) -> None:
        """Draw the target as a flat red disc on the plate at ``xy`` (m, plate frame) in the frames :meth:`render`
        makes from now on (a visual body only: the ball rolls over it)."""
        c = self._client
        if self._target_body is None:
            shape = c.createVisualShape(pb.GEOM_CYLINDER, radius=0.008, length=0.001, rgbaColor=[0.9, 0.1, 0.1, 1])
            self._target_body = c.createMultiBody(0.0, -1, shape)
        _, orientation = self._pb_base_pose(self.plate)
        lift = 0.0006 - self.ball_spec.radius  # on the surface, not at the ball's centre height
        c.resetBasePositionAndOrientation(self._target_body, self._plate_point(np.asarray(xy), lift).tolist(),
                                          orientation)  # fmt: skip

    def place_ball(self, xy: np.ndarray, velocity_xy: np.ndarray = (0.0, 0.0)) -> None:
        """Put the ball on the plate at ``xy`` (m, plate frame) rolling with ``velocity_xy`` (m/s, plate frame)."""
        ball, c = self._ball_body(), self._client
        _, rot = self._plate_frame()
        vel, omega = self._rolling_velocity(velocity_xy, rot)
        c.resetBasePositionAndOrientation(ball, self._plate_point(np.asarray(xy)).tolist(), [0, 0, 0, 1])
        c.resetBaseVelocity(ball, vel.tolist(), omega.tolist())

    def ball_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ball position and velocity in the platform frame: ((3,) m, (3,) m/s).

        x, y lie in the plate; z is the height of the ball centre above the
        platform frame origin (``plate_top + radius`` while it rests on the plate).
        """
        vel, _ = self._pb_base_velocity(self._ball_body())
        _, rot = self._plate_frame()
        return np.array(self.ball_position()), np.array(vel) @ rot

    def ball_position(self) -> tuple[float, float, float]:
        """Ball centre (x, y, z) in the platform frame, m, as Python floats (the cheap part of :meth:`ball_state`)."""
        (bx, by, bz), _ = self._pb_base_pose(self._ball_body())
        (px, py, pz), orn = self._pb_base_pose(self.plate)
        m = pb.getMatrixFromQuaternion(orn)  # R row by row
        dx, dy, dz = bx - px, by - py, bz - pz
        cx, cy, cz = self._plate_com_list
        # Rᵀ (ball − plate centre of mass) + centre of mass in the plate frame, in scalar arithmetic (hot path)
        return (m[0] * dx + m[3] * dy + m[6] * dz + cx, m[1] * dx + m[4] * dy + m[7] * dz + cy,
                m[2] * dx + m[5] * dy + m[8] * dz + cz)  # fmt: skip

    def ball_world_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ball position (3,) m and velocity (3,) m/s in the world (base) frame."""
        ball = self._ball_body()
        return np.array(self._pb_base_pose(ball)[0]), np.array(self._pb_base_velocity(ball)[0])

    # -------------------------------------------------------------- render
    def render(self) -> np.ndarray | None:
        """An RGB frame (height, width, 3) uint8 for ``rgb_array``; None for ``human`` (the GUI shows it)."""
        if self.render_mode != "rgb_array":
            return None
        width, height = self.render_size
        c = self._client
        target = [0.0, 0.0, self.geometry.home_height * 0.55]
        distance = max(0.58, 1.95 * max(self.geometry.plate_extent))  # the reference view, widened for a big plate
        view = c.computeViewMatrixFromYawPitchRoll(target, distance, 35.0, -20.0, 0.0, 2)
        proj = c.computeProjectionMatrixFOV(45.0, width / height, 0.01, 5.0)
        _, _, rgba, _, _ = c.getCameraImage(width, height, view, proj, renderer=pb.ER_TINY_RENDERER,
                                            lightDirection=[0.4, -0.6, 1.0], shadow=0)  # fmt: skip
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]

    def camera_image(self, camera: CameraSpec, markers: MarkerLayout | None = None,
                     ball_rgb: tuple[float, float, float] = (1.0, 0.45, 0.0)) -> np.ndarray:  # fmt: skip
        """What ``camera`` sees now: a BGR image (height, width, 3) uint8 for the vision pipeline.

        The camera sits on the plate's axis at home, ``camera.distance_m`` above
        the plate surface (``mount="above"``), looking down with +y up in the
        image. The plate carries ``markers`` (ArUco, black on a white quiet zone,
        drawn as thin boxes on its surface; default :class:`MarkerLayout`) and the
        ball is drawn in ``ball_rgb``. TinyRenderer, headless, lit from the
        camera so that the ball's shading is symmetric.
        """
        if camera.mount != "above":
            raise ValueError("camera_image renders a camera above the plate (markers seen from below are mirrored)")
        markers = markers or MarkerLayout()
        c = self._client
        if self._marker_body is None or self._marker_layout != markers:
            if self._marker_body is not None:
                c.removeBody(self._marker_body)
            self._marker_body, self._marker_layout = self._make_markers(markers), markers
        origin, _ = self._plate_frame()
        c.resetBasePositionAndOrientation(self._marker_body, origin.tolist(), self._pb_base_pose(self.plate)[1])
        if self.ball is not None:
            c.changeVisualShape(self.ball, -1, rgbaColor=[*ball_rgb, 1.0])
        width, height = camera.resolution
        top = self.geometry.home_position + np.array([0.0, 0.0, self.mechanism.plate_top])
        view = c.computeViewMatrix((top + [0.0, 0.0, camera.distance_m]).tolist(), top.tolist(), [0.0, 1.0, 0.0])
        fov_v = 2 * math.degrees(math.atan(math.tan(math.radians(camera.fov_deg) / 2) * height / width))
        proj = c.computeProjectionMatrixFOV(fov_v, width / height, 0.01, camera.distance_m + 1.0)
        _, _, rgba, _, _ = c.getCameraImage(width, height, view, proj, renderer=pb.ER_TINY_RENDERER,
                                            lightDirection=[0.0, 0.0, 1.0], shadow=0)  # fmt: skip
        if self.ball is not None:
            c.changeVisualShape(self.ball, -1, rgbaColor=[0.85, 0.85, 0.9, 1])
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]
        return np.ascontiguousarray(rgb[:, :, ::-1])

    def _make_markers(self, layout: MarkerLayout) -> int:
        """A visual-only body in the platform frame: per marker a white quiet zone and its black cells."""
        import cv2

        c = self._client
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, layout.dictionary))
        cells = dictionary.markerSize + 2
        z0 = self.mechanism.plate_top
        halves, positions, colours = [], [], []
        for index, marker_id in enumerate(layout.ids):
            img = cv2.aruco.generateImageMarker(dictionary, int(marker_id), cells)  # one pixel per cell
            cx, cy = (v / 1e3 for v in layout.centres_mm[index])
            side = layout.size_mm / 1e3
            cell = side / cells
            halves.append([0.75 * side, 0.75 * side, MARKER_FACE_HEIGHT / 4])
            positions.append([cx, cy, z0 + MARKER_FACE_HEIGHT / 4])
            colours.append([1.0, 1.0, 1.0, 1.0])
            for row in range(cells):  # row 0 is the marker's top, toward +y
                col = 0
                while col < cells:
                    if img[row, col] == 0:
                        end = col
                        while end + 1 < cells and img[row, end + 1] == 0:
                            end += 1
                        halves.append([(end - col + 1) * cell / 2, cell / 2, MARKER_FACE_HEIGHT / 4])
                        positions.append([cx - side / 2 + (col + end + 1) * cell / 2,
                                          cy + side / 2 - (row + 0.5) * cell, z0 + 3 * MARKER_FACE_HEIGHT / 4])  # fmt: skip
                        colours.append([0.0, 0.0, 0.0, 1.0])
                        col = end + 1
                    else:
                        col += 1
        body_visuals = []
        for h, p, rgba in zip(halves, positions, colours):  # one fixed link per box, on a massless base
            body_visuals.append(c.createVisualShape(pb.GEOM_BOX, halfExtents=h, visualFramePosition=p, rgbaColor=rgba))
        base = body_visuals[0]
        return c.createMultiBody(0.0, -1, base, [0, 0, 0], linkMasses=[0.0] * (len(body_visuals) - 1),
                                 linkCollisionShapeIndices=[-1] * (len(body_visuals) - 1),
                                 linkVisualShapeIndices=body_visuals[1:],
                                 linkPositions=[[0, 0, 0]] * (len(body_visuals) - 1),
                                 linkOrientations=[[0, 0, 0, 1]] * (len(body_visuals) - 1),
                                 linkInertialFramePositions=[[0, 0, 0]] * (len(body_visuals) - 1),
                                 linkInertialFrameOrientations=[[0, 0, 0, 1]] * (len(body_visuals) - 1),
                                 linkParentIndices=[0] * (len(body_visuals) - 1),
                                 linkJointTypes=[pb.JOINT_FIXED] * (len(body_visuals) - 1),
                                 linkJointAxis=[[0, 0, 1]] * (len(body_visuals) - 1))  # fmt: skip

    # ------------------------------------------------------------ lifecycle
    def close(self) -> None:
        """Disconnect and remove temporary files; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        client = getattr(self, "_client", None)
        if client is not None:
            try:
                client.disconnect()
            except pb.error:
                pass
        shutil.rmtree(self._tmp, ignore_errors=True)


    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            self.close()
