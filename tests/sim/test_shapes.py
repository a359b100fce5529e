"""The procedural training shapes: the seen kinds' primitives, graspable, at rest as they lie, never an
evaluation kind."""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim import objects
from hil_sim.world import TABLE_Z, World


@pytest.fixture(scope="module")
def shapes_world() -> World:
    world = World(kinds=objects.GROUPS["shapes"])
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


@pytest.mark.parametrize("kind", objects.GROUPS["shapes"])
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
