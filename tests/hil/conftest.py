"""HIL fixtures: one simulated world per module (its startup costs seconds), a state recorder per test."""

import pytest

from hil_sim.server import SimConfig, SimServer
from tests.hil.rig import StateLog
from tests.runtime import handmade
from tests.runtime.fakes import free_addresses


@pytest.fixture(scope="module")
def sim():
    camera, robot = free_addresses()
    config = SimConfig(camera=camera, robot=robot)
    with SimServer(config) as server:
        yield server


@pytest.fixture()
def state_log(sim):
    log = StateLog(sim.config.robot)
    log.wait(lambda s: True, timeout=10, what="any state")
    yield log
    log.close()


@pytest.fixture(scope="session")
def handmade_model(tmp_path_factory):
    """A contract-conforming policy whose every action is a small constant joint delta (visible motion)."""
    return handmade.build(tmp_path_factory.mktemp("models") / "handmade.onnx")
