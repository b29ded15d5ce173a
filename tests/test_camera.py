"""Camera sensing: the analytic model, the env with a camera, the OpenCV pipeline on rendered frames, the camera
config, ``camera-check`` and ``deploy --sensor camera`` through the CLI."""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

import cv2
import gymnasium as gym
import numpy as np
import pytest
from conftest import Board, FakeDevice, sg

from stewart_gym.camera import CAMERA_PRESETS, CameraSpec, SimulatedCamera
from stewart_gym.errors import ConfigError
from stewart_gym.kinematics import inverse_kinematics
from stewart_gym.sim import StewartSim
from stewart_gym.vision import CameraConfig, locate_ball

WEBCAM = CAMERA_PRESETS["webcam30"]
CONFIG_TOML = """
[camera]
source = "{source}"
resolution = [640, 480]
fps = 30
fov_deg = 60

[markers]
dictionary = "DICT_4X4_50"
ids = [0, 1, 2, 3]
centres_mm = [[-125, 125], [125, 125], [125, -125], [-125, -125]]
size_mm = 36

[ball]
hsv_low = [5, 120, 120]
hsv_high = [25, 255, 255]
radius_mm = 12.7
"""


# ------------------------------------------------------------------ model
def test_parallax_is_corrected_or_modelled() -> None:
    """A ball 100 mm off the axis: read exactly when the pipeline knows the radius; 100·d/(d − r) mm when it
    maps onto the plate (a flat target), and 100·d/(d + r) seen from below."""
    r, d = 0.0127, WEBCAM.distance_m
    exact = SimulatedCamera(replace(WEBCAM, centroid_noise_px=0.0), r)
    assert exact.detect(0.1, 0.0)[0] == pytest.approx(0.1, abs=2e-4)  # quantisation only
    flat = SimulatedCamera(replace(WEBCAM, parallax_corrected=False), r)
    assert flat.detect(0.1, 0.0)[0] == pytest.approx(0.1 * d / (d - r), abs=2e-4)
    below = SimulatedCamera(replace(WEBCAM, mount="below", parallax_corrected=False), r)
    assert below.detect(0.1, 0.0)[0] == pytest.approx(0.1 * d / (d + r), abs=2e-4)


def test_frames_latency_noise_and_misses() -> None:
    spec = replace(WEBCAM, fps=30.0, latency_s=0.05, miss_rate=0.2, centroid_noise_px=0.5)
    cam = SimulatedCamera(spec)
    cam.reset(0.0, (0.05, -0.02), np.random.default_rng(1))
    times, errors, misses = [], [], 0
    for k in range(1, 3001):
        t = k * 0.01
        cam.record(t, (0.05, -0.02), True)
        got = cam.read(t)
        if k % 4:
            continue
        if got is None:
            misses += 1
            continue
        (x, y), ts = got
        times.append((t, ts))
        errors += [x - 0.05, y + 0.02]
    assert all(ts == pytest.approx(math.floor((t - 0.05) * 30 + 1e-9) / 30) for t, ts in times)
    assert 0.15 < misses / 750 < 0.25
    sigma = float(np.std(errors))
    assert sigma == pytest.approx(0.5 * spec.mm_per_px() * 1e-3, rel=0.25)


def test_presets_see_the_reference_plate_and_bad_specs_are_refused() -> None:
    for spec in CAMERA_PRESETS.values():
        assert spec.sees((0.15, 0.15)), spec.name
    for bad in ({"fps": 0.0}, {"fov_deg": math.nan}, {"miss_rate": 1.0}, {"mount": "side"}, {"resolution": (8, 8)}):
        with pytest.raises(ConfigError):
            CameraSpec(**bad)


def test_the_env_takes_a_camera_and_randomises_over_the_presets() -> None:
    env = gym.make("StewartBallBalance-v0", sensor="pixy2")
    env.reset(seed=0)
    assert isinstance(env.unwrapped.sensor_model, SimulatedCamera)
    assert env.unwrapped.sensor_model.spec.name == "pixy2"
    env.close()
    env = gym.make("StewartBallBalance-v0", sensor="camera", randomize=True)
    names = set()
    for seed in range(12):
        env.reset(seed=seed)
        names.add(env.unwrapped.params.sensor.name)
        obs, *_ = env.step(np.zeros(2, dtype=np.float32))
        assert np.all(np.isfinite(obs))
    env.close()
    assert names == set(CAMERA_PRESETS)
    with pytest.raises(ConfigError, match="sensor"):
        gym.make("StewartBallBalance-v0", sensor="kinect")


# --------------------------------------------------------- rendered frames
def _render_set(n: int, seed: int, ball: bool) -> list[tuple[np.ndarray, np.ndarray]]:
    """(image, true ball xy mm) pairs: random positions over the plate (within the markers' square) and plate
    tilts of up to 10° in any direction, at 640×480."""
    rng = np.random.default_rng(seed)
    out = []
    with StewartSim(ball=True) as sim:
        for _ in range(n):
            sim.reset()
            angle, size = rng.uniform(0, 2 * math.pi), math.radians(10) * math.sqrt(rng.uniform())
            ik = inverse_kinematics(sim.geometry, np.array([0, 0, 0, size * math.cos(angle), size * math.sin(angle), 0]))
            sim.command(sim.calibration.pulse_widths(ik.servo_angles))
            for _ in range(20):
                sim.step()
            if ball:
                sim.place_ball(rng.uniform(-0.125, 0.125, 2))
            else:
                sim.place_ball(np.array([5.0, 5.0]))  # far off the plate and out of view
            out.append((sim.camera_image(WEBCAM), np.array(sim.ball_position()[:2]) * 1e3))
    return out


@pytest.mark.slow
def test_detection_on_rendered_frames_is_within_a_millimetre() -> None:
    """200 random ball positions with the plate tilted by up to 10°: RMS ≤ 1 mm, worst ≤ 3 mm; 50 frames without
    a ball: no detection."""
    config = CameraConfig(fov_deg=WEBCAM.fov_deg)
    errors = []
    for image, truth in _render_set(200, seed=3, ball=True):
        d = locate_ball(image, config)
        assert d.xy_mm is not None, d.reason
        errors.append(float(np.hypot(*(np.array(d.xy_mm) - truth))))
    rms, worst = float(np.sqrt(np.mean(np.square(errors)))), max(errors)
    print(f"camera pipeline on 200 rendered frames: RMS {rms:.3f} mm, worst {worst:.3f} mm")
    assert rms <= 1.0 and worst <= 3.0
    for image, _ in _render_set(50, seed=4, ball=False):
        d = locate_ball(image, config)
        assert d.xy_mm is None and d.reason.startswith("no ball") and d.markers == 4


def test_no_plate_is_said() -> None:
    blank = np.full((480, 640, 3), 255, np.uint8)
    cv2.circle(blank, (320, 240), 14, (0, 110, 255), -1)  # an orange ball and no markers
    d = locate_ball(blank, CameraConfig())
    assert d.xy_mm is None and d.reason.startswith("no plate") and d.markers == 0


# ------------------------------------------------------------- config and CLI
# The tests that take it share an xdist group: on `make test`'s workers it is still made once.
@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3 s MJPG clip rendered from the simulator (the ball rolling on a gently rocking plate) and its config."""
    folder = tmp_path_factory.mktemp("camera")
    video = folder / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30, WEBCAM.resolution)
    with StewartSim(ball=True) as sim:
        sim.place_ball(np.array([0.03, -0.02]))
        for k in range(90):
            pose = np.array([0, 0, 0, math.radians(3) * math.sin(k / 10), 0, 0])
            sim.command(sim.calibration.pulse_widths(inverse_kinematics(sim.geometry, pose).servo_angles))
            sim.step()
            image = sim.camera_image(WEBCAM)
            if k == 0:
                cv2.imwrite(str(folder / "frame.png"), image)
            writer.write(image)
    writer.release()
    (folder / "cam.toml").write_text(CONFIG_TOML.format(source=video))
    return folder


def test_camera_config_names_its_mistakes(tmp_path: Path) -> None:
    good = CONFIG_TOML.format(source=tmp_path)
    for old, new, field in [
        ('dictionary = "DICT_4X4_50"', 'dictionary = "DICT_9X9_1"', "dictionary"),
        ("ids = [0, 1, 2, 3]", "ids = [0, 1, 2]", "ids"),
        ("size_mm = 36", "size_mm = -3", "size_mm"),
        ("hsv_low = [5, 120, 120]", "hsv_low = [5, 120, 300]", "hsv_low"),
        ("fps = 30", "fps = 30\nzoom = 2", "zoom"),
        ("fps = 30", "fps = 30\nmin_ball_px = 99999999", "min_ball_px must be in 1…307200, got 99999999$"),
        ("[125, 125]", "[125]", re.escape("centres_mm must be four [x, y] pairs in mm, got [[-125, 125], [125], ")),
        (f'source = "{tmp_path}"', 'source = "missing.mp4"', "source"),
    ]:
        path = tmp_path / "c.toml"
        path.write_text(good.replace(old, new))
        with pytest.raises(ConfigError, match=field):
            CameraConfig.from_toml(path)
    with pytest.raises(ConfigError, match=f"^{re.escape(str(path))}: camera.source: "):  # (the last: missing.mp4)
        CameraConfig.from_toml(path)
    for name, value in (("camera", "3"), ("markers", "3"), ("ball", "[1]")):  # a table that is not one
        tables = [block for block in good.split("\n\n") if not block.strip().startswith(f"[{name}]")]
        path.write_text(f"{name} = {value}\n" + "\n\n".join(tables))
        with pytest.raises(ConfigError, match=f"^{re.escape(str(path))}: \\[{name}\\] must be a table"):
            CameraConfig.from_toml(path)
    (tmp_path / "v.avi").write_bytes(b"")  # a relative video path is read from the config's folder
    (tmp_path / "rel.toml").write_text(good.replace(f'source = "{tmp_path}"', 'source = "v.avi"'))
    assert CameraConfig.from_toml(tmp_path / "rel.toml").source == str(tmp_path / "v.avi")


@pytest.mark.xdist_group("camera_clip")
@pytest.mark.slow
def test_camera_check_reads_an_image_and_a_video(clip: Path, tmp_path: Path) -> None:
    one = sg("camera-check", "--camera-config", str(clip / "cam.toml"), "--image", str(clip / "frame.png"),
             "--json", cwd=tmp_path)  # fmt: skip
    assert one.returncode == 0, one.stderr
    got = json.loads(one.stdout.strip().splitlines()[-1])
    assert got["x_mm"] == pytest.approx(30.0, abs=1.0) and got["y_mm"] == pytest.approx(-20.0, abs=1.0)
    empty = tmp_path / "empty.png"
    cv2.imwrite(str(empty), cv2.imread(str(clip / "frame.png"))[:, :, ::-1] * 0 + 255)
    none = sg("camera-check", "--camera-config", str(clip / "cam.toml"), "--image", str(empty), "--json", cwd=tmp_path)
    assert none.returncode == 1 and json.loads(none.stdout.strip().splitlines()[-1])["ball"] is None
    text = sg("camera-check", "--camera-config", str(clip / "cam.toml"), "--image", str(empty), "--out",
              str(tmp_path / "new_folder" / "none.png"), cwd=tmp_path)  # fmt: skip
    assert text.returncode == 1 and text.stdout.startswith("no plate: ") and "no ball: no" not in text.stdout
    assert cv2.imread(str(tmp_path / "new_folder" / "none.png")).shape == (480, 640, 3)  # its folder made for it
    live = sg("camera-check", "--camera-config", str(clip / "cam.toml"), "--frames", "10", "--out",
              str(tmp_path / "a.png"), cwd=tmp_path)  # fmt: skip
    assert live.returncode == 0 and "ball found in 10 of 10 frames" in live.stdout, live.stderr
    assert cv2.imread(str(tmp_path / "a.png")).shape == (480, 640, 3)
    for args, says in ((["--frames", "10"], f"{tmp_path / 'a.png'} exists; give another name or --overwrite"),
                       (["--image", str(empty), "--overwrite"], "is the --image it reads")):  # fmt: skip
        target = tmp_path / "a.png" if "--frames" in args else empty
        before = target.read_bytes()
        kept = sg("camera-check", "--camera-config", str(clip / "cam.toml"), *args, "--out", str(target), cwd=tmp_path)
        assert kept.returncode == 1 and says in kept.stderr and target.read_bytes() == before, kept.stderr
    bad = sg("camera-check", "--camera-config", str(clip / "cam.toml"), "--image", str(tmp_path / "nope.png"),
             cwd=tmp_path)  # fmt: skip
    errors = [ln for ln in bad.stderr.splitlines() if ln.startswith("error:")]
    assert bad.returncode == 1 and len(errors) == 1 and "nope.png" in errors[0]
    (tmp_path / "notes.txt").write_text("my notes\n")  # a source that is no video: the user's mistake (exit 1)
    config = tmp_path / "notes_cam.toml"
    config.write_text(re.sub(r'source = "[^"]*"', f'source = "{tmp_path / "notes.txt"}"',
                             (clip / "cam.toml").read_text()))  # fmt: skip
    text_source = sg("camera-check", "--camera-config", str(config), cwd=tmp_path)
    assert text_source.returncode == 1 and text_source.stderr.strip().splitlines() == [
        f"error: {config}: camera.source '{tmp_path / 'notes.txt'}' is not a video OpenCV can read"], text_source.stderr
    config.write_text(re.sub(r'source = "[^"]*"', f'source = "{tmp_path}"', (clip / "cam.toml").read_text()))
    folder_source = sg("camera-check", "--camera-config", str(config), cwd=tmp_path)  # a folder: exit 1 too
    assert folder_source.returncode == 1 and folder_source.stderr.strip().splitlines() == [
        f"error: {config}: camera.source '{tmp_path}' is a folder, not a video file or a camera"], folder_source.stderr


@pytest.mark.xdist_group("camera_clip")
def test_camera_check_on_a_pipe_nobody_writes_to_says_so_within_seconds(clip: Path, tmp_path: Path) -> None:
    """Opening a named pipe waits for a writer, inside OpenCV, deaf to Ctrl-C and to SIGTERM: camera-check waits
    5 s for the first frame, as deploy does, and then says what is wrong in one line (exit 2, a device failure)."""
    import os

    pipe = tmp_path / "stream.mjpg"
    os.mkfifo(pipe)
    config = tmp_path / "pipe_cam.toml"
    config.write_text(re.sub(r'source = "[^"]*"', f'source = "{pipe}"', (clip / "cam.toml").read_text()))
    waited = sg("camera-check", "--camera-config", str(config), "--frames", "5", cwd=tmp_path, timeout=120)  # (a hang
    # fails here, at the timeout)
    assert waited.returncode == 2 and waited.stderr.strip().splitlines() == [
        f"error: camera '{pipe}' delivered no frame within 5 s (nothing writing to the pipe? a camera in use or "
        "hung?)"], waited.stderr  # fmt: skip
    assert not (tmp_path / "camera_check.png").exists()


@pytest.mark.xdist_group("camera_clip")
def test_camera_check_with_an_empty_out_is_refused(clip: Path, tmp_path: Path, capfd) -> None:
    """``--out ""`` is a mistake, not a request for the default camera_check.png."""
    from conftest import cli

    code, _, err = cli(capfd, "camera-check", "--camera-config", str(clip / "cam.toml"), "--out", "", cwd=tmp_path)
    assert code == 1 and err.strip() == "error: an empty output path was given; name the file to write", err
    assert not (tmp_path / "camera_check.png").exists()


@pytest.mark.xdist_group("camera_clip")
@pytest.mark.parametrize("source", ["folder", "text"])
def test_deploy_with_a_camera_source_that_is_no_video_names_the_config(clip: Path, tmp_path: Path, capfd,
                                                                       source: str) -> None:  # fmt: skip
    """A source that is a folder, or a file that is no video, is the config's mistake: deploy names the file and
    the field in one line (exit 1), as camera-check does, before any port opens."""
    from conftest import cli

    target = tmp_path if source == "folder" else tmp_path / "notes.txt"
    if source == "text":
        target.write_text("my notes\n")
    config = tmp_path / "cam_src.toml"
    config.write_text(re.sub(r'source = "[^"]*"', f'source = "{target}"', (clip / "cam.toml").read_text()))
    code, out, err = cli(capfd, "deploy", "--policy", "pid", "--sensor", "camera", "--camera-config", str(config),
                         "--port", str(tmp_path / "no_board"), "--protocol", "maestro", "--duration", "1")  # fmt: skip
    says = "is a folder, not a video file or a camera" if source == "folder" else "is not a video OpenCV can read"
    assert code == 1 and err.strip().splitlines() == [f"error: {config}: camera.source '{target}' {says}"], err


@pytest.mark.xdist_group("camera_clip")
def test_deploy_with_the_camera_reading_a_rendered_video(clip: Path, tmp_path: Path, device: FakeDevice) -> None:
    drain = Board(device)
    dep = sg("deploy", "--policy", "pid", "--sensor", "camera", "--camera-config", str(clip / "cam.toml"), "--port",
             device.path, "--protocol", "maestro", "--duration", "2", "--log", str(tmp_path / "d.csv"),
             cwd=tmp_path)  # fmt: skip
    drain.stop()
    assert dep.returncode == 0, dep.stdout + dep.stderr
    assert "camera: ball found in" in dep.stdout
    found, frames = (int(v) for v in dep.stdout.split("camera: ball found in ")[1].split(" frames")[0].split(" of "))
    assert frames >= 45 and found == frames  # 30 fps for 2 s, every frame read
    assert "source ended" not in dep.stdout  # the 3 s clip outlasts the run
    assert len(drain.frames) >= 90 and all(np.all((f >= 1000) & (f <= 2000)) for f in drain.frames)
    no_config = sg("deploy", "--policy", "pid", "--sensor", "camera", "--port", device.path, cwd=tmp_path)
    assert no_config.returncode == 1 and "--camera-config" in no_config.stderr


@pytest.mark.xdist_group("camera_clip")
def test_a_raw_mjpeg_file_plays_at_the_configs_frame_rate(clip: Path, tmp_path: Path, device: FakeDevice) -> None:
    """A raw MJPEG file stores no frame rate (OpenCV says 25 fps): ``deploy`` plays it at ``camera.fps``, here 60."""
    video = cv2.VideoCapture(str(clip / "clip.avi"))
    with (tmp_path / "clip.mjpg").open("wb") as f:
        while True:
            ok, image = video.read()
            if not ok:
                break
            f.write(cv2.imencode(".jpg", image)[1].tobytes())
    video.release()
    config = tmp_path / "cam.toml"
    config.write_text((clip / "cam.toml").read_text().replace(str(clip / "clip.avi"), str(tmp_path / "clip.mjpg"))
                      .replace("fps = 30", "fps = 60"))  # fmt: skip
    drain = Board(device)
    dep = sg("deploy", "--policy", "pid", "--sensor", "camera", "--camera-config", str(config), "--port", device.path,
             "--protocol", "maestro", "--duration", "1", "--log", str(tmp_path / "d.csv"), cwd=tmp_path)  # fmt: skip
    drain.stop()
    assert dep.returncode == 0, dep.stdout + dep.stderr
    frames = int(dep.stdout.split("camera: ball found in ")[1].split(" frames")[0].split(" of ")[1])
    assert 45 <= frames <= 75, dep.stdout  # 60 a second for 1 s (at OpenCV's 25 it would be about 25)


@pytest.mark.xdist_group("camera_clip")
def test_a_camera_that_never_finds_the_ball_sends_the_platform_home(clip: Path, tmp_path: Path,
                                                                    device: FakeDevice) -> None:  # fmt: skip
    """Frames with the plate but no ball: no detection ever arrives, so the watchdog holds the platform at home,
    as for a silent touch panel, and the run fails. The video (0.5 s) ends before the run (1 s): the summary says at
    which tick."""
    video = tmp_path / "empty.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30, WEBCAM.resolution)
    with StewartSim(ball=True) as sim:
        sim.place_ball(np.array([5.0, 5.0]))  # out of view
        image = sim.camera_image(WEBCAM)
    for _ in range(15):
        writer.write(image)
    writer.release()
    config = tmp_path / "cam.toml"
    config.write_text((clip / "cam.toml").read_text().replace(str(clip / "clip.avi"), str(video)))
    drain = Board(device)
    dep = sg("deploy", "--policy", "pid", "--sensor", "camera", "--camera-config", str(config), "--port", device.path,
             "--protocol", "maestro", "--duration", "1", "--log", str(tmp_path / "d.csv"), cwd=tmp_path)  # fmt: skip
    drain.stop()
    # no fresh reading on any tick: the platform was held home, and the run fails (it did not balance anything)
    assert dep.returncode == 1 and "failed: no fresh valid reading" in dep.stdout, dep.stdout + dep.stderr
    assert "camera: ball found in 0 of" in dep.stdout
    ended = re.search(r"the sensor's source ended at tick (\d+) \(the video ran out\)", dep.stdout)
    assert ended and 10 <= int(ended[1]) <= 45, dep.stdout  # 0.5 s of a 1 s run at 50 Hz
    import csv

    rows = list(csv.DictReader((tmp_path / "d.csv").open()))
    assert rows and all(int(r["stale"]) and int(r["homing"]) for r in rows)


def test_a_camera_config_written_as_toml_reads_back_equal(tmp_path: Path) -> None:
    """``CameraConfig.to_toml`` writes what ``from_toml`` reads back to an equal config: every field, the
    markers and the ball included."""
    from stewart_gym.vision import BallColour, MarkerLayout

    (tmp_path / "clip.mp4").write_bytes(b"")
    configs = [CameraConfig(source=3),
               CameraConfig(source=str(tmp_path / "clip.mp4"), resolution=(316, 208), fps=59.94, fov_deg=72.5,
                            markers=MarkerLayout("DICT_5X5_100", (7, 3, 9, 1),
                                                 ((-90.5, 80.0), (90.0, 80.0), (90.0, -80.0), (-90.0, -80.25)), 28.5),
                            ball=BallColour((0, 90, 80), (12, 250, 255), 20.0), min_ball_px=30)]  # fmt: skip
    for i, config in enumerate(configs):
        (tmp_path / f"c{i}.toml").write_text(config.to_toml())
        assert CameraConfig.from_toml(tmp_path / f"c{i}.toml") == config

