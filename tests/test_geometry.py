"""Geometry presets, TOML loading and validation."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from stewart_gym.geometry import GeometryError, PlatformGeometry
from stewart_gym.presets import load_geometry, load_preset, preset_names

MM = 1e-3


def test_preset_names() -> None:
    assert set(preset_names()) == {"servo-hexapod", "memememe-liverpool", "desk-rect", "senilov2018", "mathcad-micro"}
    with pytest.raises(GeometryError, match="known presets"):
        load_preset("nope")


def test_presets_are_immutable(preset: PlatformGeometry) -> None:
    with pytest.raises(ValueError):
        preset.base_anchors[0, 0] = 1.0
    with pytest.raises(AttributeError):
        preset.rod_length = 1.0  # type: ignore[misc]


def test_memememe_matches_reference() -> None:
    g = load_preset("memememe-liverpool")
    base_deg = [314.9, 345.1, 74.9, 105.1, 194.9, 225.1]
    top_deg = [322.9, 337.1, 82.9, 97.1, 202.9, 217.1]
    for i in range(6):
        assert g.base_anchors[i, :2] == pytest.approx(
            [65.43 * MM * math.cos(math.radians(base_deg[i])), 65.43 * MM * math.sin(math.radians(base_deg[i]))]
        )
        assert g.platform_anchors[i, :2] == pytest.approx(
            [76.35 * MM * math.cos(math.radians(top_deg[i])), 76.35 * MM * math.sin(math.radians(top_deg[i]))]
        )
    assert g.servo_beta == pytest.approx([-8 * math.pi / 3, math.pi / 3, 0, -math.pi, -4 * math.pi / 3, -7 * math.pi / 3])
    assert (g.horn_length, g.rod_length) == pytest.approx((36 * MM, 125 * MM))
    # The initial height is the given 120 mm, not eq. 10's value (which differs).
    assert g.home_height == pytest.approx(0.120)
    assert abs(g.home_heights_eq10()[0] - 0.120) > 5 * MM


def test_senilov_matches_seed_001() -> None:
    g = load_preset("senilov2018")
    dt = 10
    b_deg = [330 + dt, 90 - dt, 90 + dt, 210 - dt, 210 + dt, 330 - dt]
    p_deg = [30 - dt, 30 + dt, 150 - dt, 150 + dt, 270 - dt, 270 + dt]
    for i in range(6):
        b = np.radians(b_deg[i])
        p = np.radians(p_deg[i])
        assert g.base_anchors[i] == pytest.approx([0.5 * math.cos(b), 0.5 * math.sin(b), 0.02])
        assert g.platform_anchors[i] == pytest.approx([0.2 * math.cos(p), 0.2 * math.sin(p), 0.0])
    assert g.kind == "linear" and g.home_height == 0.25
    assert g.leg_length_range == pytest.approx((0.2, 0.5))  # stroke 0…0.3 m on a 0.2 m fixed part


def test_mathcad_matches_seed_002() -> None:
    g = load_preset("mathcad-micro")
    assert g.base_anchors[:, 0] / MM == pytest.approx([4, 26, 22, -22, -26, -4])
    assert g.base_anchors[:, 1] / MM == pytest.approx([27.7, -10.39, -17.32, -17.32, -10.39, 27.7])
    assert g.platform_anchors[:, 0] / MM == pytest.approx([5.5, 7.5, 2, -2, -7.5, -5.5])
    assert g.platform_anchors[:, 1] / MM == pytest.approx([5.48, 2.02, -7.5, -7.5, 2.02, 5.48])
    assert g.home_height == pytest.approx(22.19 * MM)
    assert np.array(g.leg_length_range) / MM == pytest.approx([31.44 - 1.24, 31.44 + 1.24])


def test_servo_hexapod_is_documented_reference() -> None:
    g = load_preset("servo-hexapod")
    assert g.horn_length == pytest.approx(0.025) and g.rod_length == pytest.approx(0.160)
    assert g.home_heights_eq10() == pytest.approx(np.full(6, g.home_height), abs=1e-12)
    assert g.home_height == pytest.approx(0.15961, abs=1e-5)
    assert np.max(np.linalg.norm(g.platform_anchors[:, :2], axis=1)) < 0.150  # anchors under a 300 mm plate
    lo, hi = g.servo_angle_range
    assert math.degrees(hi - lo) == pytest.approx(90.0)


def test_toml_round_trip(preset: PlatformGeometry, tmp_path: Path) -> None:
    path = tmp_path / "g.toml"
    path.write_text(preset.to_toml())
    back = PlatformGeometry.from_toml(path)
    assert back == preset
    assert np.array_equal(back.base_anchors, preset.base_anchors)
    assert load_geometry(path) == preset


GOOD = """
name = "test"
length_unit = "mm"
angle_unit = "deg"
base_anchors = [[100, 0, 0], [0, 100, 0], [-100, 0, 0], [0, -100, 0], [60, 80, 0], [-60, -80, 0]]
platform_anchors = [[80, 0, 0], [0, 80, 0], [-80, 0, 0], [0, -80, 0], [48, 64, 0], [-48, -64, 0]]
horn_length = 25
rod_length = 160
servo_beta = [90, 180, 270, 0, 135, 315]
servo_angle_range = [-45, 45]
"""


def test_toml_units_and_eq10_home_height(tmp_path: Path) -> None:
    path = tmp_path / "g.toml"
    path.write_text(GOOD)
    g = PlatformGeometry.from_toml(path)
    assert g.rod_length == pytest.approx(0.160)
    assert g.servo_angle_range == pytest.approx((-math.pi / 4, math.pi / 4))
    # eq. 10 with 20 mm radial offset on every leg
    assert g.home_height == pytest.approx(math.sqrt(0.160**2 + 0.025**2 - 0.020**2))


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (("base_anchors = [[100, 0, 0], [0, 100, 0]", "base_anchors = [[100, 0], [0, 100, 0]"), "base_anchors"),
        (("rod_length = 160", "rod_length = -160"), "rod_length"),
        (("rod_length = 160", "rod_length = nan"), "rod_length"),
        (("rod_length = 160", "rod_length = \"long\""), "rod_length"),
        (("rod_length = 160\n", ""), "rod_length"),
        (("horn_length = 25", "horn_length = 0"), "horn_length"),
        (("servo_beta = [90, 180, 270, 0, 135, 315]", "servo_beta = [90, 180]"), "servo_beta"),
        (("servo_angle_range = [-45, 45]", "servo_angle_range = [45, -45]"), "servo_angle_range"),
        (("servo_angle_range = [-45, 45]\n", ""), "servo_angle_range"),
        (("platform_anchors = [[80, 0, 0]", "platform_anchors = [[inf, 0, 0]"), "platform_anchors"),
        (("name = \"test\"", "name = \"test\"\nwheels = 4"), "wheels"),
        (("length_unit = \"mm\"", "length_unit = \"inch\""), "length_unit"),
    ],
)
def test_bad_toml_names_the_field(tmp_path: Path, edit: tuple[str, str], field: str) -> None:
    old, new = edit
    assert old in GOOD
    path = tmp_path / "bad.toml"
    path.write_text(GOOD.replace(old, new, 1))
    with pytest.raises(GeometryError, match=field):
        PlatformGeometry.from_toml(path)


SYMMETRIC = {  # the presets built in three pairs, as [symmetric] describes them (mm, degrees)
    "servo-hexapod": ({"horn_length": 25, "rod_length": 160},
                      {"base_radius": 100, "base_pair_angle": 40, "platform_radius": 80, "platform_pair_angle": 16}),
    "desk-rect": ({"horn_length": 30, "rod_length": 190},
                  {"base_radius": 120, "base_pair_angle": 36, "platform_radius": 95, "platform_pair_angle": 18}),
}  # fmt: skip


def toml_text(top: dict, symmetric: dict) -> str:
    """A geometry TOML in mm and degrees: ``top``'s keys, then the ``[symmetric]`` table (values as TOML text)."""
    lines = ['length_unit = "mm"', 'angle_unit = "deg"', *(f"{k} = {v}" for k, v in top.items()), "[symmetric]",
             *(f"{k} = {v}" for k, v in symmetric.items())]  # fmt: skip
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("name", sorted(SYMMETRIC))
def test_a_symmetric_description_gives_the_presets_anchors(name: str, tmp_path: Path) -> None:
    """``[symmetric]``: four numbers instead of 42, the presets' anchors, horn directions and eq. 10 home height to
    1e-9 (the presets place each anchor by its own angle list, independently)."""
    preset = load_preset(name)
    low, high = (float(v) for v in np.degrees(preset.servo_angle_range))
    top, table = SYMMETRIC[name]
    path = tmp_path / f"{name}.toml"
    path.write_text(toml_text({"name": f'"{name}"', **top, "servo_angle_range": f"[{low!r}, {high!r}]"}, table))
    geo = load_geometry(path)
    assert np.max(np.abs(geo.base_anchors - preset.base_anchors)) < 1e-9
    assert np.max(np.abs(geo.platform_anchors - preset.platform_anchors)) < 1e-9
    assert np.max(np.abs(np.angle(np.exp(1j * (geo.servo_beta - preset.servo_beta))))) < 1e-9
    assert abs(geo.home_height - preset.home_height) < 1e-9
    assert geo.servo_angle_range == pytest.approx(preset.servo_angle_range, abs=1e-9)


@pytest.mark.parametrize(("key", "value", "says"), [
    ("base_pair_angle", "0", r"symmetric\.base_pair_angle: between 0 and 120"),
    ("base_pair_angle", "130", r"symmetric\.base_pair_angle: between 0 and 120"),
    ("platform_radius", "-80", r"symmetric\.platform_radius"),
    ("platform_radius", '"80"', r"symmetric\.platform_radius"),
    ("platform_radius", "nan", r"symmetric\.platform_radius"),
    ("wheel_radius", "3", r"symmetric: unknown field\(s\) \['wheel_radius'\]"),
    ("platform_pair_angle", None, r"symmetric: missing \['platform_pair_angle'\]"),
])  # fmt: skip
def test_a_bad_symmetric_description_names_the_field(key: str, value: str | None, says: str, tmp_path: Path) -> None:
    top, table = SYMMETRIC["servo-hexapod"]
    table = {k: v for k, v in {**table, key: value}.items() if v is not None}
    path = tmp_path / "bad.toml"
    path.write_text(toml_text({**top, "servo_angle_range": "[-30, 60]"}, table))
    with pytest.raises(GeometryError, match=says):
        load_geometry(path)


def test_symmetric_and_explicit_anchors_are_one_or_the_other(tmp_path: Path) -> None:
    top, table = SYMMETRIC["servo-hexapod"]
    path = tmp_path / "both.toml"
    path.write_text(toml_text({**top, "servo_angle_range": "[-30, 60]", "servo_beta": "[0, 0, 0, 0, 0, 0]"}, table))
    with pytest.raises(GeometryError, match="symmetric: .* may not give servo_beta as well"):
        load_geometry(path)


def test_measured_anchors_load_and_far_apart_legs_warn(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Anchors measured to 0.1 mm (servo-hexapod's, off by up to 0.05 mm and rounded) load with eq. 10's mean
    home height, silently; legs that disagree by more than 1 mm load too, with one warning line naming the spread
    and what to check."""
    preset = load_preset("servo-hexapod")
    rng = np.random.default_rng(0)
    fields = {"horn_length": preset.horn_length, "rod_length": preset.rod_length,
              "servo_beta": preset.servo_beta.tolist(), "servo_angle_range": list(preset.servo_angle_range)}  # fmt: skip
    measured = PlatformGeometry.from_dict({
        **fields,
        "base_anchors": (np.round(preset.base_anchors * 1e4 + rng.uniform(-0.5, 0.5, (6, 3))) / 1e4).tolist(),
        "platform_anchors": (np.round(preset.platform_anchors * 1e4 + rng.uniform(-0.5, 0.5, (6, 3))) / 1e4).tolist(),
    }, source="measured.toml")  # fmt: skip
    assert not caplog.records
    assert abs(measured.home_height - preset.home_height) < 0.2 * MM
    bent = preset.base_anchors.copy()
    bent[0, 2] += 2 * MM  # one servo shaft 2 mm higher: its leg's home height 2 mm off the others'
    PlatformGeometry.from_dict({**fields, "base_anchors": bent.tolist(), "platform_anchors":
                                preset.platform_anchors.tolist()}, source="bent.toml")  # fmt: skip
    [record] = caplog.records
    assert record.getMessage().startswith("warning: bent.toml: eq. 10 gives home heights ")
    assert "using their mean" in record.getMessage() and "\n" not in record.getMessage()


def test_invalid_toml_syntax(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("rod_length = = 3")
    with pytest.raises(GeometryError, match="not valid TOML"):
        PlatformGeometry.from_toml(path)


def test_linear_needs_home_height_and_range() -> None:
    base = load_preset("senilov2018")
    with pytest.raises(GeometryError, match="leg_length_range"):
        PlatformGeometry("x", base.base_anchors, base.platform_anchors, 0.2, 0.25)
    with pytest.raises(GeometryError, match="home_height"):
        PlatformGeometry.from_dict(
            {"base_anchors": base.base_anchors.tolist(), "platform_anchors": base.platform_anchors.tolist(),
             "rod_length": 0.2, "leg_length_range": [0.2, 0.5]}
        )  # fmt: skip


def test_plate_size_round_trips_and_is_checked(tmp_path: Path) -> None:
    geo = load_preset("desk-rect")
    assert geo.plate_extent == (0.400, 0.260)
    path = tmp_path / "g.toml"
    path.write_text(geo.to_toml())
    assert PlatformGeometry.from_toml(path) == geo
    text = geo.to_toml().replace("plate_size = [0.4, 0.26]", "plate_size = [400, -1]")
    path.write_text(text)
    with pytest.raises(GeometryError, match="plate_size"):
        PlatformGeometry.from_toml(path)
    assert load_preset("senilov2018").plate_extent == (0.5, 0.5)


def test_the_own_platform_pages_symmetric_file_is_servo_hexapod(tmp_path: Path) -> None:
    """The first TOML block of docs/src/own-platform.md loads as written and places servo-hexapod's anchors."""
    page = (Path(__file__).resolve().parents[1] / "docs" / "src" / "own-platform.md").read_text()
    block = page.split("```toml\n", 1)[1].split("```", 1)[0]
    assert "[symmetric]" in block
    path = tmp_path / "my.toml"
    path.write_text(block)
    geo, preset = load_geometry(path), load_preset("servo-hexapod")
    assert geo.name == "my-platform" and geo.plate_size == pytest.approx((0.3, 0.3))
    assert np.max(np.abs(geo.base_anchors - preset.base_anchors)) < 1e-9
    assert np.max(np.abs(geo.platform_anchors - preset.platform_anchors)) < 1e-9
    assert np.max(np.abs(np.angle(np.exp(1j * (geo.servo_beta - preset.servo_beta))))) < 1e-9


@pytest.mark.parametrize("name", ["servo-hexapod", "senilov2018"])
def test_a_file_whose_travel_misses_home_is_refused_naming_the_range(name: str, tmp_path: Path) -> None:
    """A build's home must be inside its actuators' travel (else it has no neutral pulse): the file and the range
    are named, for a rotary and a linear build, while every preset loads from its own file."""
    from stewart_gym.kinematics import inverse_kinematics

    geo = load_preset(name)
    home = inverse_kinematics(geo, np.zeros(6)).actuators
    key = "servo_angle_range" if geo.is_rotary else "leg_length_range"
    lo, hi = getattr(geo, key)
    path = tmp_path / "g.toml"
    path.write_text(geo.to_toml())
    assert load_geometry(path) == geo and np.all((lo <= home) & (home <= hi))
    above = float(home.max()) + 1e-3  # the travel starts just above home
    text = geo.to_toml()
    start = text.index(f"{key} = [")
    end = text.index("]", start) + 1
    path.write_text(text[:start] + f"{key} = [{above!r}, {hi!r}]" + text[end:])
    with pytest.raises(GeometryError, match=rf"^{re.escape(str(path))}: {key}: .* does not hold the .* at home"):
        load_geometry(path)


def test_a_symmetric_descriptions_mistakes_name_its_own_fields(tmp_path: Path) -> None:
    """A ``[symmetric]`` file gives radii and pair angles, not anchors: its errors name them, in its own units."""
    head = 'name = "s"\nhorn_length = 0.025\nrod_length = 0.16\nservo_angle_range = [-0.7, 0.7]\n'
    for unit, table, says in (
            ('length_unit = "m"\nangle_unit = "deg"\nhome_height = 0.16',
             "base_radius = 100\nbase_pair_angle = 40\nplatform_radius = 0.08\nplatform_pair_angle = 16",
             r"symmetric.base_radius: 100 m is larger than any build"),
            ('angle_unit = "rad"', "base_radius = 0.1\nbase_pair_angle = 40\nplatform_radius = 0.08\n"
             "platform_pair_angle = 0.3", r"symmetric.base_pair_angle: .* got 40 in the file's angle_unit \(2291.83°\)")):
        (tmp_path / "s.toml").write_text(f"{unit}\n{head}[symmetric]\n{table}\n")
        with pytest.raises(GeometryError, match=says):
            load_geometry(tmp_path / "s.toml")


def test_a_build_with_one_leg_given_twice_is_refused_naming_the_legs(tmp_path: Path) -> None:
    """Its Jacobian at home is singular: forward kinematics then called a wrong pose converged."""
    import dataclasses

    from stewart_gym.presets import load_geometry, load_preset

    g = load_preset("servo-hexapod")
    base, top, beta = g.base_anchors.copy(), g.platform_anchors.copy(), g.servo_beta.copy()
    base[1], top[1], beta[1] = base[0], top[0], beta[0]
    path = tmp_path / "twice.toml"
    path.write_text(dataclasses.replace(g, base_anchors=base, platform_anchors=top, servo_beta=beta).to_toml())
    with pytest.raises(GeometryError, match=r"twice.toml: the legs cannot hold the plate at home \(legs 0 and 1 are "
                                            "one leg twice"):  # fmt: skip
        load_geometry(str(path))


def test_a_length_that_is_not_a_number_is_called_so(tmp_path: Path) -> None:
    from stewart_gym.presets import load_geometry

    path = tmp_path / "nan.toml"
    path.write_text(load_geometry("servo-hexapod").to_toml().replace("home_height = ", "home_height = nan #", 1))
    with pytest.raises(GeometryError, match="home_height: must be a finite length, got nan"):
        load_geometry(str(path))


def test_the_layout_and_the_constructor_check_what_a_file_is_checked_for() -> None:
    """What ``from_dict`` refuses in a file, the Python calls refuse too: a negative or NaN radius, a pair angle in
    degrees, a name that is not text, a length in millimetres."""
    import dataclasses

    from stewart_gym.geometry import symmetric_layout
    from stewart_gym.presets import load_geometry, load_preset

    for args, named in (((-0.1, 0.3, 0.08, 0.3), "base_radius"), ((0.1, 0.3, math.nan, 0.3), "platform_radius"),
                        ((0.1, 20.0, 0.08, 0.3), "base_pair_angle")):  # fmt: skip
        with pytest.raises(GeometryError, match=named):
            symmetric_layout(*args)
    g = load_preset("servo-hexapod")
    with pytest.raises(GeometryError, match="name"):
        dataclasses.replace(g, name=5)
    with pytest.raises(GeometryError, match="rod_length: larger than any build"):
        dataclasses.replace(g, rod_length=160.0)  # mm taken for m
    for spec in (None, 123):
        with pytest.raises(GeometryError, match="a preset's name"):
            load_geometry(spec)
