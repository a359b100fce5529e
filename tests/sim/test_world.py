"""The MuJoCo world: loads every kind, holds still, places objects in the workspace, rejects bad input."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim import objects
from hil_sim.world import HOME_Q, TABLE_Z, WORKSPACE_X, WORKSPACE_Y, World, WorldError


def test_world_has_panda_gripper_and_all_kinds(world: World) -> None:
    assert world.model.nu == 9  # 7 arm position actuators + 2 finger actuators
    assert set(world.kinds) == set(objects.SEEN) | set(objects.UNSEEN)
    assert len(objects.SEEN) == len(objects.UNSEEN) == 6


@pytest.mark.parametrize("kind", objects.SEEN + objects.UNSEEN)
def test_every_kind_rests_on_the_table_inside_the_workspace(world: World, kind: str) -> None:
    world.reset(kind, seed=3)
    pos, _ = world.object_pose()
    assert WORKSPACE_X[0] - 0.02 <= pos[0] <= WORKSPACE_X[1] + 0.02
    assert WORKSPACE_Y[0] - 0.02 <= pos[1] <= WORKSPACE_Y[1] + 0.02
    half = world.object_extent()
    assert TABLE_Z < pos[2] < TABLE_Z + 2 * max(half) + 0.01, "object fell through or floats"
    assert 2 * min(half[:2]) < 0.078, "narrow side must fit the 8 cm gripper"


@pytest.mark.parametrize("kind", objects.SEEN + objects.UNSEEN)
def test_every_kind_left_alone_stays_where_it_was_put(world: World, kind: str) -> None:
    """A kind that rolls away on its own (a lemon with a round cross-section did, 20 cm in 10 s on these
    seeds) is a moving target no grasp planner should be asked to hit."""
    for seed in (10002, 10003, 10004):
        world.reset(kind, seed=seed)
        start, _ = world.object_pose()
        world.set_targets(world.q, -1.0)
        world.step(5.0)
        assert np.linalg.norm(world.object_pose()[0][:2] - start[:2]) < 0.005, f"{kind} seed {seed} rolled"


def test_arm_holds_still_without_nan(world: World) -> None:
    world.reset("cube", seed=0, randomise=False)
    start_obj, _ = world.object_pose()
    world.set_targets(np.asarray(HOME_Q), -1.0)
    for _ in range(50):  # 5 s
        world.step(0.1)
        assert np.all(np.isfinite(world.data.qpos)) and np.all(np.isfinite(world.data.qvel))
    assert np.max(np.abs(world.q - HOME_Q)) < 0.01
    assert np.max(np.abs(world.dq)) < 0.01
    assert world.gripper_opening == pytest.approx(0.08, abs=0.002)
    assert np.linalg.norm(world.object_pose()[0] - start_obj) < 0.005


def test_position_targets_are_tracked(world: World) -> None:
    world.reset("cube", seed=0, randomise=False)
    target = np.asarray(HOME_Q) + [0.2, -0.1, 0.1, 0.15, -0.2, 0.1, 0.3]
    world.set_targets(target, 1.0)
    world.step(2.0)
    assert np.max(np.abs(world.q - target)) < 0.02
    assert world.gripper_opening < 0.005


def test_gripper_points_down_at_home(world: World) -> None:
    world.reset("apple", seed=0, randomise=False)
    assert world.ee_xmat()[:, 2] @ [0, 0, -1] > 0.99
    assert world.ee_pose()[0][2] - TABLE_Z == pytest.approx(0.40, abs=0.03)


def test_unknown_kind_is_one_clear_error() -> None:
    with pytest.raises(objects.UnknownObjectError, match="unknown object kind 'dragonfruit'"):
        World(kinds=("dragonfruit",))


def test_kind_not_in_world_is_rejected_at_reset(world: World) -> None:
    with pytest.raises(objects.UnknownObjectError, match="not in this world"):
        world.reset("teapot", seed=0)


def test_missing_asset_is_one_clear_error(tmp_path) -> None:
    with pytest.raises(objects.MissingAssetError, match="does not exist"):
        World(kinds=(str(tmp_path / "nope.stl"),))
    bad = tmp_path / "thing.ply"
    bad.write_text("ply")
    with pytest.raises(objects.MissingAssetError, match="unsupported format"):
        World(kinds=(str(bad),))


def _write_obj_box(path, half=(0.03, 0.02, 0.025)) -> None:
    hx, hy, hz = half
    verts = [(sx * hx, sy * hy, sz * hz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    faces = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    lines = [f"v {x} {y} {z}" for x, y, z in verts] + [f"f {' '.join(map(str, f))}" for f in faces]
    path.write_text("\n".join(lines) + "\n")


def test_user_mesh_and_mjcf_objects_load_and_rest(tmp_path) -> None:
    mesh = tmp_path / "my box.obj"
    _write_obj_box(mesh)
    mjcf = tmp_path / "toy.xml"
    mjcf.write_text('<mujoco><worldbody><body name="toy"><geom type="capsule" size="0.02 0.03"/>'
                    '</body></worldbody></mujoco>')
    w = World(kinds=(str(mesh), str(mjcf)))
    for kind in w.kinds:
        w.reset(kind, seed=1)
        pos, _ = w.object_pose()
        assert TABLE_Z < pos[2] < TABLE_Z + 0.1
    assert w.object_extent()[2] == pytest.approx(0.05, abs=0.002)  # capsule: half length + radius


def test_bad_commands_are_rejected(world: World) -> None:
    world.reset("cube", seed=0)
    with pytest.raises(WorldError, match="7 finite"):
        world.set_targets(np.zeros(6), 1.0)
    with pytest.raises(WorldError, match="7 finite"):
        world.set_targets(np.full(7, np.nan), 1.0)


def test_the_world_renders_headless_whichever_module_imports_mujoco_first() -> None:
    """With no MUJOCO_GL set, a trainer module that imports mujoco before any hil_sim one (the scripted
    expert) still leaves MuJoCo on headless EGL: before, it fell to GLFW and the first render failed on a
    server (`trainer evaluate --sensor stereo --workers 1`)."""
    import os
    import subprocess
    import sys

    code = ("import trainer.teacher.scripted\nfrom hil_sim.world import World\n"
            "w = World(['cube']); w.reset('cube', 0); print(w.render_policy_depth().shape)")
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "(96, 128)", done.stderr[-500:]
