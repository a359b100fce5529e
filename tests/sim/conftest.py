"""One compiled world per test module: building it (meshes, 12 objects) costs about half a second."""

from __future__ import annotations

import pytest

from hil_sim.world import World


@pytest.fixture(scope="module")
def world() -> World:
    w = World()
    yield w
    w.close()
