"""What ``deploy`` does before anything moves: every input checked, the sensor ready, then the port.

:class:`DeploySetup` takes a loaded policy (a :class:`~stewart_gym.hardware.export.BundlePolicy`) and the
user's :class:`DeployOptions`, and checks all of them at construction: the bundle's own fields, the
calibration and its ``[hardware]`` table, the camera config, the sensor against the protocol, the log path.
:meth:`DeploySetup.run` then builds the sensor (a camera must deliver its first frame; the simulated plant
starts), opens the port, asks the board once whether it answers (unless ``write_only``), and runs the
:class:`~stewart_gym.hardware.deploy.DeployLoop`. Until the loop starts, a failure or a stop signal closes
what was opened and leaves the servos unmoved.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.calibration import CalibrationError, ServoCalibration
from stewart_gym.errors import ConfigError
from stewart_gym.hardware.deploy import (
    DEFAULT_SLEW_US_PER_S,
    MAX_HOME_S,
    MAX_STEP_US,
    DeployConfig,
    DeployLoop,
    DeploySummary,
    PanelSensor,
    SimulatedPlant,
)
from stewart_gym.hardware.serial_controllers import (
    ANSWER_TIMEOUT_S,
    PROTOCOLS,
    DeviceError,
    LineController,
    check_channels,
    open_controller,
)

__all__ = ["LOG_FOLDER", "DeployOptions", "DeploySetup", "load_calibration", "new_log_name", "port_settings"]

#: Line speeds a serial port can be given, baud.
BAUD_RANGE = (300, 4_000_000)


def load_calibration(path: str | None, geometry: Any, used_for: str = "the policy") -> tuple[ServoCalibration, dict]:
    """The calibration for ``geometry`` (trims, directions, limits from ``path`` if given) and its ``[hardware]``
    table, checked (``port`` text, ``protocol`` one of :data:`PROTOCOLS`, ``baudrate`` a whole number in
    :data:`BAUD_RANGE`). A calibration file that names another geometry is refused, naming both and
    ``used_for`` (what the geometry came from: "the policy", "--geometry").

    A relative ``geometry`` path inside the file is read from the file's own folder."""
    from stewart_gym.calibration import hardware_settings
    from stewart_gym.presets import load_geometry
    from stewart_gym.tomlio import read_toml

    geo = load_geometry(geometry)
    if not path:
        return ServoCalibration.default(geo), {}
    data = read_toml(path, CalibrationError, "calibration file")
    declared, digest = data.get("geometry"), data.get("geometry_sha256")
    if digest is not None and (not isinstance(digest, str) or re.fullmatch(r"[0-9a-f]{64}", digest) is None):
        raise CalibrationError(f"{path}: geometry_sha256 must be the 64 hex digits calibrate writes, got {digest!r}")
    if declared is not None:
        if not isinstance(declared, str) or not declared:
            raise CalibrationError(f"{path}: geometry must be a preset name or a TOML path, got {declared!r}")
        if declared.endswith(".toml") and not Path(declared).is_absolute():
            declared = str(Path(path).parent / declared)
        if digest is not None and declared.endswith(".toml") and not Path(declared).is_file():  # the file moved:
            # its content decides
            if digest != geo.content_hash():
                raise ConfigError(f"{path} is a calibration for the geometry in {declared}, which is not there, and "
                                  f"{used_for} ({geo.name!r}) is another build (its content differs): give the "
                                  "calibration of this build, or calibrate it")  # fmt: skip
            declared = None
    if declared is not None:
        try:
            other = load_geometry(declared)
        except ValueError as exc:
            raise CalibrationError(f"{path}: its geometry {declared!r} cannot be loaded ({exc})") from None
        if digest is not None and other.content_hash() != digest:
            if not declared.endswith(".toml"):  # a preset: this version's differs, or the digest was edited
                raise ConfigError(f"{path}: its geometry_sha256 is not that of the preset {declared!r} (a calibration "
                                  "from another version, or an edited digest): calibrate the build again "
                                  "(stewart-gym calibrate)")  # fmt: skip
            raise ConfigError(f"{declared} has changed since {path} was calibrated for it: calibrate the build again "
                              "(stewart-gym calibrate), or restore the geometry file")  # fmt: skip
        if other != geo:
            raise ConfigError(f"{path} is a calibration for geometry {other.name!r}, but {used_for} is for "
                              f"{geo.name!r}: calibrate this build (stewart-gym calibrate --geometry …), or give "
                              "the calibration of this build")  # fmt: skip
    hw = hardware_settings(path)
    port, protocol, baud = hw.get("port"), hw.get("protocol"), hw.get("baudrate")
    if port is not None and (not isinstance(port, str) or not port):
        raise CalibrationError(f"{path}: hardware.port must be a device path, got {port!r}")
    if protocol is not None and protocol not in PROTOCOLS:
        raise CalibrationError(f"{path}: hardware.protocol must be one of {sorted(PROTOCOLS)}, got {protocol!r}")
    if baud is not None and (isinstance(baud, bool) or not isinstance(baud, int)
                             or not BAUD_RANGE[0] <= baud <= BAUD_RANGE[1]):  # fmt: skip
        raise CalibrationError(f"{path}: hardware.baudrate must be a whole number of baud in "
                               f"{BAUD_RANGE[0]}…{BAUD_RANGE[1]:,}, got {baud!r}")  # fmt: skip
    try:
        calibration = ServoCalibration.from_toml(path, geo)
    except (ConfigError, ValueError) as exc:  # the field named, and the file too
        text = str(exc)
        raise CalibrationError(text if text.startswith(str(path)) else f"{path}: {text}") from None
    return calibration, hw


def port_settings(port: str | None, protocol: str | None, baudrate: int | None,
                  hw: dict) -> tuple[str, str, int | None]:  # fmt: skip
    """(port, protocol, baud rate): the options given, else the calibration's ``[hardware]``, else the defaults."""
    port = port or hw.get("port")
    if not port:
        raise ConfigError("no serial port: give --port, or a calibration file with [hardware] port")
    return str(port), protocol or hw.get("protocol", "maestro"), baudrate or hw.get("baudrate")


#: Where a deploy run's log goes unless ``--log`` says (a folder that git ignores in a checkout).
LOG_FOLDER = "out"


def new_log_name(folder: str | Path = ".") -> str:
    """``deploy_log_<date>-<time>.csv`` in ``folder``, with -2, -3, … if that exists: never an old log."""
    stem = Path(folder) / f"deploy_log_{time.strftime('%Y%m%d-%H%M%S')}"
    name, k = f"{stem}.csv", 1
    while Path(name).exists():
        k += 1
        name = f"{stem}-{k}.csv"
    return name


@dataclass(frozen=True)
class DeployOptions:
    """What the user chose (``stewart-gym deploy``'s options)."""

    port: str | None = None
    protocol: str | None = None
    baudrate: int | None = None
    sensor: str = "sim"  # sim | panel | camera
    camera_config: str | None = None
    calibration: str | None = None
    backend: str | None = None
    rate_hz: float = 50.0
    duration_s: float | None = None
    watchdog_s: float = 0.1
    max_step_us: float | None = None
    trajectory: str | None = None
    log: str | None = None
    overwrite: bool = False
    seed: int = 0
    randomize: bool = True
    write_only: bool = False
    answer_timeout_s: float = ANSWER_TIMEOUT_S
    twin: dict | None = None  # the simulated plant's platform (--sensor sim): a twin's tables


class DeploySetup:
    """A deploy run, checked and ready (see the module's description). ``say`` prints a line for the user."""

    def __init__(self, policy: Any, options: DeployOptions, say: Any = print) -> None:
        from stewart_gym.actions import ActionMapper
        from stewart_gym.envs import ENV_IDS
        from stewart_gym.envs.task import load_task
        from stewart_gym.outputs import output_file

        self.policy, self.options, self.say = policy, options, say  # the bundle's fields (its observation layout
        # too) were checked as it loaded
        self.calibration, hw = load_calibration(options.calibration, policy.geometry)
        self.port, self.protocol, self.baudrate = port_settings(options.port, options.protocol, options.baudrate, hw)
        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"protocol must be one of {sorted(PROTOCOLS)}, got {self.protocol!r}")
        check_channels(self.protocol, self.calibration.channels, options.calibration or "the default calibration")
        self.camera_config = None
        if options.sensor == "sim":
            import importlib.util

            if importlib.util.find_spec("gymnasium") is None or (importlib.util.find_spec("pybullet") is None
                                                                 and importlib.util.find_spec("mujoco") is None):
                raise ConfigError("--sensor sim needs the simulator: pip install 'stewart_gym[sim]' (or use --sensor "
                                  "panel)")  # fmt: skip
            if options.backend == "mujoco" and importlib.util.find_spec("mujoco") is None:
                raise ConfigError("--backend mujoco needs MuJoCo: pip install 'stewart_gym[mujoco]'")
        elif options.backend:
            raise ConfigError("--backend chooses the simulated plant's engine: it needs --sensor sim")
        elif options.twin is not None:
            raise ConfigError("--twin describes the simulated plant: it needs --sensor sim")
        if options.sensor == "camera":
            if not options.camera_config:
                raise ConfigError("--sensor camera needs --camera-config FILE (see stewart-gym camera-check)")
            from stewart_gym.vision import CameraConfig

            self.camera_config = CameraConfig.from_toml(options.camera_config)
        elif options.camera_config:
            raise ConfigError("--camera-config goes with --sensor camera")
        elif options.sensor not in ("sim", "panel"):
            raise ConfigError(f"--sensor must be sim, panel or camera, got {options.sensor!r}")
        if options.sensor == "panel" and self.protocol != "line":
            raise ConfigError("--sensor panel needs --protocol line (the Arduino sketch reports the panel)")
        if not (math.isfinite(options.answer_timeout_s) and 0.05 <= options.answer_timeout_s <= 60):
            raise ConfigError(f"the board's answer timeout must be 0.05…60 s, got {options.answer_timeout_s!r}")
        env_id = policy.env_id
        if env_id not in ENV_IDS:
            raise ConfigError(f"the policy was exported for {env_id!r}, which is not an env of this version")
        task_kwargs = {k: v for k, v in policy.meta.get("env_kwargs", {}).items() if k == "trajectory"}
        self.task = load_task(ENV_IDS[env_id][0], **task_kwargs)
        if options.trajectory and not self.task.moving_target:
            raise ConfigError(f"--trajectory needs a track policy (StewartBallTrack-v0); this one is for {env_id}")
        if options.trajectory:
            self.task = load_task(ENV_IDS[env_id][0], **{**task_kwargs, "trajectory": options.trajectory})
        self.log = options.log or new_log_name(LOG_FOLDER)
        output_file(self.log, suffixes=(".csv",), overwrite=options.overwrite)
        Path(self.log).parent.mkdir(parents=True, exist_ok=True)
        self.mapper = ActionMapper(policy.geometry, self.calibration, policy.action_mode, max_tilt=policy.max_tilt)
        max_step = options.max_step_us or min(DEFAULT_SLEW_US_PER_S / options.rate_hz, MAX_STEP_US)
        travel = float(np.max(self.calibration.max_us - self.calibration.min_us))
        home_s = travel / (max_step * options.rate_hz)  # from one end of the widest channel at the rate limit
        if home_s > MAX_HOME_S:
            raise ConfigError(f"--max-step-us {max_step:g} at {options.rate_hz:g} Hz moves a servo "
                              f"{max_step * options.rate_hz:g} µs/s: from the end of its travel ({travel:g} µs) the "
                              f"drive home would take {home_s:.0f} s; give --max-step-us "
                              f"{travel / (MAX_HOME_S * options.rate_hz):.3g} or more (home within "
                              f"{MAX_HOME_S:g} s)")  # fmt: skip
        self.config = DeployConfig(rate_hz=options.rate_hz, duration_s=options.duration_s,
                                   watchdog_s=options.watchdog_s, max_step_us=max_step, log_path=self.log,
                                   home_timeout_s=max(2.0, 1.5 * home_s))  # fmt: skip
        self.task.reset(np.random.default_rng(options.seed), None)  # the target only: no disturbances on hardware

    def _sensor_first(self) -> Any:
        """The sensor that needs no port, built before it opens: the camera (its first frame awaited) or the
        simulated plant. None for the panel, which the board reports."""
        o = self.options
        width, depth = self.policy.geometry.plate_extent
        if o.sensor == "camera":
            from stewart_gym.hardware.camera_sensor import CameraSensor

            try:
                return CameraSensor(self.camera_config, plate_half=(width / 2, depth / 2))  # type: ignore[arg-type]
            except ConfigError as exc:  # the config's source: name the file
                raise ConfigError(f"{o.camera_config}: {exc}") from None
        if o.sensor == "sim":
            return SimulatedPlant(self.policy.env_id, seed=o.seed, randomize=o.randomize, geometry=self.policy.geometry,
                                  backend=o.backend or "auto", twin=o.twin)  # fmt: skip
        return None

    def run(self) -> DeploySummary:
        """Sensor, port, the board's first answer, then the loop; the loop's summary, with what the sensor saw."""
        sensor = self._sensor_first()
        controller = None
        try:
            cal = self.calibration
            controller = open_controller(self.protocol, self.port, cal.channels, self.baudrate, (cal.min_us, cal.max_us),
                                         self.options.calibration or "the default calibration")  # fmt: skip
            if isinstance(controller, LineController):
                sensor = sensor or PanelSensor(controller)
            held = None  # the pulses the board says it holds now
            if not self.options.write_only:
                held = controller.held_pulses(max(1.0, self.options.answer_timeout_s), attempts=3)
                if held is None:
                    hint = ("flash arduino/stewart_pca9685 of this version, which answers '?'"
                            if self.protocol == "line" else "check that its TX line is wired to this computer")
                    raise DeviceError(f"the board on {self.port} did not answer a position query: {hint}; if its "
                                      "replies are not wired, deploy with --write-only (homing then goes "
                                      "unconfirmed); nothing was moved")  # fmt: skip
                controller.monitor(self.options.answer_timeout_s)
            if self.task.moving_target:
                self.say(f"tracking a {getattr(self.task, 'current_trajectory', 'moving')} target ({self.policy.env_id})")
            plant = sensor if isinstance(sensor, SimulatedPlant) else None
            loop = DeployLoop(self.policy, self.mapper, controller, sensor, self.config, self.task.target, plant=plant)
            if held is not None and np.all((held >= cal.min_us) & (held <= cal.max_us)) and not np.allclose(
                    held, loop.safety.home, atol=controller.resolution_us + 0.5):  # fmt: skip
                # servos held elsewhere (a board that did not reset): the first frames start from there, rate-limited
                # (a channel off, 0, or outside its limits: where the servo is is not known, and home is the start)
                loop.safety.reset(held)
                self.say(f"the board holds {', '.join(f'{w:.0f}' for w in held)} µs: the first frames move from "
                         "there at the rate limit")  # fmt: skip
        except BaseException:
            for part in (controller, sensor):
                close = getattr(part, "close", None)
                if close is not None:
                    close()
            raise
        summary = loop.run()
        camera = getattr(sensor, "frames", None)
        if camera is not None:
            summary.message += f"; camera: ball found in {sensor.found} of {sensor.frames} frames"
        if isinstance(sensor, SimulatedPlant) and sensor.final_error_mm is not None:
            summary.message += f"; simulated ball {sensor.final_error_mm:.1f} mm from the centre"
        return summary
