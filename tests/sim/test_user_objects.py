"""User objects by path: MuJoCo loads the file (any geom spelling, nested bodies, defaults, meshes beside
it) and the world keeps the mass and friction written there; a file the world cannot use is refused in one
line."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hil_sim import objects
from hil_sim.world import HOME_Q, TABLE_Z, World

DATA = Path(__file__).resolve().parents[1] / "data" / "objects"
BELL_MASS, WOOD_DENSITY = 0.06, 700.0
HANDLE_VOLUME = math.pi * 0.01**2 * 0.09 + 4 / 3 * math.pi * 0.01**3  # capsule r 1 cm between +-4.5 cm
HEX_VOLUME = 3 * math.sqrt(3) / 2 * 0.02**2 * 0.09  # hexagon of circumradius 2 cm, 9 cm long
FILES = {  # file: (mass, frictions of its colliding geoms), as written in the file
    "capsule_fromto.xml": (0.09, [0.7]),
    "quat_box.xml": (600.0 * 0.09 * 0.04 * 0.05, [0.6]),
    "nested_default.xml": (2 * BELL_MASS + WOOD_DENSITY * HANDLE_VOLUME, [0.5, 1.1, 1.1]),
    "hexbar.xml": (0.1, [0.8]),
    "hexbar.obj": (objects.MESH_DENSITY * HEX_VOLUME, [1.0]),  # a bare mesh: MuJoCo's defaults
}


@pytest.fixture(scope="module")
def user_world() -> World:
    w = World(kinds=tuple(str(DATA / name) for name in FILES))
    yield w
    w.close()


@pytest.mark.parametrize("name", FILES)
def test_user_object_has_the_mass_and_friction_of_its_file(user_world: World, name: str) -> None:
    mass, frictions = FILES[name]
    obj = user_world._ids.objects[str(DATA / name)]
    # rel 1e-4: the .obj's vertices are written to the micrometre
    assert user_world.model.body_subtreemass[obj.body] == pytest.approx(mass, rel=1e-4)
    assert user_world.model.geom_friction[obj.geoms, 0] == pytest.approx(frictions)


@pytest.mark.parametrize("name", FILES)
def test_user_object_rests_centred_with_its_narrow_side_along_x(user_world: World, name: str) -> None:
    kind = str(DATA / name)
    user_world.reset(kind, seed=5)
    half = user_world.object_extent()
    user_world.step(1.0)
    pos, quat = user_world.object_pose()
    assert pos[2] - TABLE_Z == pytest.approx(half[2], abs=0.002), "its centre should be half its height up"
    assert abs(quat[1]) + abs(quat[2]) < 0.01, "it should lie as its file poses it"
    assert half[0] <= half[1] and 2 * half[0] < objects.MAX_WIDTH_M


def test_turned_and_nested_geoms_are_measured_in_the_object_frame(user_world: World) -> None:
    user_world.reset(str(DATA / "quat_box.xml"), seed=0)  # a 9 x 4 x 5 cm box turned 30 deg by its quat
    assert user_world.object_extent() == pytest.approx([0.02, 0.045, 0.025], abs=1e-6)
    user_world.reset(str(DATA / "nested_default.xml"), seed=0)  # bells 2.2 cm r, 9 cm apart
    assert user_world.object_extent() == pytest.approx([0.022, 0.067, 0.022], abs=5e-4)


def test_every_body_of_a_parked_object_is_inert_and_an_active_one_collides(user_world: World) -> None:
    """The nested body is parked with the rest: no contacts, no gravity (else it sags under the floor)."""
    kind = str(DATA / "nested_default.xml")
    obj = user_world._ids.objects[kind]
    assert len(obj.bodies) == 3 and len(obj.geoms) == 3  # free body, the file's body, its nested one
    m = user_world.model
    user_world.reset(str(DATA / "quat_box.xml"), seed=0)
    assert not m.geom_contype[obj.geoms].any() and (m.body_gravcomp[obj.bodies] == 1).all()
    user_world.reset(kind, seed=0)
    assert m.geom_contype[obj.geoms].all() and not m.body_gravcomp[obj.bodies].any()


def _write(tmp_path: Path, body: str, name: str = "thing.xml") -> str:
    path = tmp_path / name
    path.write_text(f"<mujoco><worldbody>{body}</worldbody></mujoco>")
    return str(path)


@pytest.mark.parametrize(("body", "needle"), [
    ('<geom type="box" size="0.02 0.02 0.02"/>', "must hold one top body .* found none"),
    ('<body name="a"><geom size="0.02"/></body><body name="b"><geom size="0.02"/></body>', "found 'a', 'b'"),
    ('<body><freejoint/><geom type="box" size="0.06 0.05 0.02"/></body>', "10.0 cm across its narrower"),
    ('<body name="a"><geom size="0.02"/><body name="lid"><joint name="h"/><geom size="0.01"/></body></body>',
     "joint 'h' in body 'lid'; an object is one rigid body"),
    ('<body><geom type="ellipsoid" size="0.02 0.03 0.05" euler="40 0 0"/></body>', "does not come to rest"),
    ('<body><geom type="capsule" size="0.02"/></body>', "size 1 must be positive"),
    ('<body><geom size="0.02" mass="0"/></body>', "mass and inertia of moving bodies"),
    ('<body><geom size="0.02" contype="0" conaffinity="0"/></body>', "no geom that collides"),
])
def test_a_file_the_world_cannot_use_is_refused_in_one_line(tmp_path: Path, body: str, needle: str) -> None:
    with pytest.raises(objects.InvalidObjectError, match=needle) as err:
        World(kinds=(_write(tmp_path, body),))
    assert "\n" not in str(err.value) and "thing.xml" in str(err.value)


def test_a_file_mujoco_cannot_parse_is_refused_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(objects.InvalidObjectError, match="unrecognized attribute: 'colour'") as err:
        objects.resolve(_write(tmp_path, '<body><geom size="0.02" colour="red"/></body>'))
    assert "\n" not in str(err.value)


def test_kinds_are_selected_by_group_or_list_and_each_checked_before_any_work(tmp_path: Path) -> None:
    assert objects.select_kinds("seen") == objects.GROUPS["seen"]
    assert objects.select_kinds(f"cube,,{DATA / 'hexbar.obj'}") == ("cube", str(DATA / "hexbar.obj"))
    with pytest.raises(objects.ObjectError, match="no object kinds in ','"):
        objects.select_kinds(",")
    with pytest.raises(objects.UnknownObjectError, match="'dragonfruit'"):
        objects.select_kinds("cube,dragonfruit")
    with pytest.raises(objects.MissingAssetError, match="does not exist"):
        objects.select_kinds(str(tmp_path / "gone.stl"))


BUILTIN_REFERENCE = {  # kind, seed: half extent, object position after 0.5 s, first 3 joints; before issue 46
    ("banana", 5): ([0.09774877748993396, 0.034328009770575686, 0.02251479288666156],
                    [0.5915010193229461, 0.1231757796875836, 0.7679644441654336],
                    [0.09993035139480835, -0.2014231004934571, 0.09928247723019032]),
    ("starfruit", 6): ([0.05000000074505846, 0.02894500084221386, 0.0304300002753737],
                       [0.5048525479063058, -0.06881244632349598, 0.7758339158780689],
                       [0.09921185633981217, -0.20077721334662363, 0.0973771030600741]),
    ("pear", 7): ([0.033, 0.033, 0.046], [0.537529, 0.158886, 0.7947970027788441],
                  [0.09955016369095475, -0.20059295947375055, 0.09969603811779315]),
}


def test_builtin_episodes_are_those_before_user_objects_were_loaded_by_mujoco(world: World) -> None:
    """Built-in kinds are still written into the scene's MJCF: the same seed gives the same episode."""
    for (kind, seed), (half, pos, q) in BUILTIN_REFERENCE.items():
        world.reset(kind, seed)
        world.set_targets(np.asarray(HOME_Q) + 0.1, 1.0)
        world.step(0.5)
        assert world.object_extent().tolist() == pytest.approx(half, rel=1e-12, abs=1e-15)
        assert world.object_pose()[0].tolist() == pytest.approx(pos, rel=1e-9)
        assert world.q[:3].tolist() == pytest.approx(q, rel=1e-9)


def test_evaluate_and_collect_take_user_objects_by_path(tmp_path: Path, capsys) -> None:
    from trainer.collect import main as collect_main
    from trainer.eval.success import main as evaluate_main

    kinds = [str(DATA / "capsule_fromto.xml"), str(DATA / "hexbar.obj")]
    result = tmp_path / "eval.json"
    assert evaluate_main(["--episodes", "2", "--objects", ",".join(kinds), "--workers", "1",
                          "--json", str(result)]) == 0
    assert list(json.loads(result.read_text())["per_object"]) == kinds
    rows = capsys.readouterr().out.splitlines()
    assert [row.split()[0] for row in rows[1:3]] == kinds
    assert collect_main(["--episodes", "1", "--objects", kinds[1], "--workers", "1", "--no-depth",
                         "--out", str(tmp_path / "demos.zarr")]) == 0


def test_evaluate_refuses_an_unusable_file_in_one_line(tmp_path: Path, capsys) -> None:
    from trainer.eval.success import main as evaluate_main

    wide = _write(tmp_path, '<body><geom type="box" size="0.06 0.05 0.02"/></body>')
    assert evaluate_main(["--episodes", "1", "--workers", "1", "--objects", wide]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: object") and "across its narrower" in err and "\n" not in err
