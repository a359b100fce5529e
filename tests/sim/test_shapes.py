"""The procedural training shapes and square boxes: the seen kinds' primitives, graspable, at rest as they
lie, never an evaluation kind."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim import objects
from hil_sim.world import TABLE_Z, World

TRAINING = objects.GROUPS["shapes"] + objects.GROUPS["squares"] + objects.GROUPS["superquadrics"]


@pytest.fixture(scope="module")
def shapes_world() -> World:
    world = World(kinds=TRAINING)
    yield world
    world.close()


def test_shapes_use_only_the_seen_kinds_primitives_and_stay_out_of_the_evaluation_groups() -> None:
    types = {g.type for k in objects.SHAPES for g in k.geoms}
    assert types == {"box", "ellipsoid", "capsule"}  # no cylinder or mesh: can, wheel, starfruit
    names = objects.GROUPS["shapes"]
    assert len(set(names)) == objects.SHAPE_COUNT
    assert not set(names) & set(objects.GROUPS["all"])
    assert objects.GROUPS["train"] == objects.SEEN + names
    assert objects.select_kinds("train") == objects.GROUPS["train"]


def test_squares_are_boxes_round_to_the_labels_and_kept_out_of_train() -> None:
    """Square in plan, so their label has no grasp direction (as the cube's); the expert may close across the
    diagonal, so that must fit the gripper too."""
    from trainer.sim.labels import grasp_yaw

    for kind in objects.SQUARES:
        (geom,) = kind.geoms
        assert geom.type == "box"
        assert not grasp_yaw(np.array([1.0, 0, 0, 0]), np.array(geom.size)).any(), kind.name
        assert 2 * np.hypot(*geom.size[:2]) < objects.MAX_WIDTH_M, kind.name
    names = objects.GROUPS["squares"]
    assert not set(names) & set(objects.GROUPS["train"] + objects.GROUPS["all"])
    assert objects.select_kinds("seen,squares,can") == objects.SEEN + names + ("can",)


def test_scaled_kinds_are_the_seen_kinds_scaled_and_kept_out_of_train() -> None:
    """Every geom's sizes and place grow by one factor per kind, a smaller and a larger copy where it fits."""
    for kind in objects.SCALED:
        base, _, percent = kind.name.partition("_x")
        scale, source = int(percent) / 100, objects.KINDS[base]
        assert base in objects.SEEN and (0.75 <= scale <= 0.9 or 1.1 <= scale <= 1.3), kind.name
        for geom, original in zip(kind.geoms, source.geoms, strict=True):
            assert geom.type == original.type, kind.name
            np.testing.assert_allclose(geom.size, np.array(original.size) * scale, atol=1e-4)
            np.testing.assert_allclose(geom.pos, np.array(original.pos) * scale, atol=1e-4)
    assert {k.name.partition("_x")[0] for k in objects.SCALED} == set(objects.SEEN)
    assert not set(objects.GROUPS["scaled"]) & set(objects.GROUPS["train"] + objects.GROUPS["all"])


def test_superquadrics_are_convex_meshes_of_drawn_forms_kept_out_of_train() -> None:
    """Each is one mesh whose points lie on its superquadric's surface, within the half extents drawn."""
    corners = []  # how far each form reaches into its box's corners: 2 a box's, 1.41 an ellipse's (in plan)
    for kind in objects.SUPERQUADRICS:
        (geom,) = kind.geoms
        assert geom.type == "mesh" and geom.mesh == kind.name, kind.name
        pts = np.array(kind.mesh_vertices).reshape(-1, 3)
        half = np.abs(pts).max(axis=0)
        assert half[0] >= half[1] >= objects.MIN_HALF - 1e-6, "y is the narrow side"
        corners.append((np.abs(pts[:, :2]) / half[:2]).sum(axis=1).max())
    assert min(corners) < 1.5 and max(corners) > 1.8, "the family spans square and round plans, not one form"
    names = objects.GROUPS["superquadrics"]
    assert len(set(names)) == objects.SUPERQUADRIC_COUNT
    assert not set(names) & set(objects.GROUPS["train"] + objects.GROUPS["all"])


@pytest.mark.parametrize("kind", TRAINING)
def test_every_shape_rests_as_it_lies_and_fits_the_gripper(shapes_world: World, kind: str) -> None:
    shapes_world.reset(kind, seed=5)
    start, _ = shapes_world.object_pose()
    shapes_world.step(1.0)
    pos, _ = shapes_world.object_pose()
    half = shapes_world.object_extent()
    assert np.linalg.norm(pos - start) < 0.003, "a shape must not roll or topple on its own"
    assert pos[2] - TABLE_Z == pytest.approx(half[2], abs=0.004), "it lies on its bottom face"
    assert objects.MIN_HALF - 1e-6 <= min(half[:2]) <= 0.03625, "4-7.2 cm across the narrow side"
    assert half[2] >= objects.MIN_HALF - 1e-6, "at least 4 cm tall"
