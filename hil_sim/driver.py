"""``python -m hil_sim.driver [--bind ADDR]``: the simulated Panda behind the robot driver, until SIGTERM.

The same server, wire protocol, safety layer and options as ``python -m runtime.franka_driver`` (the real
Franka); the arm is a MuJoCo world of its own, stepped in real time by a physics thread.
"""

from __future__ import annotations

import sys

from hil_sim.driver_backend import MujocoBackend
from hil_sim.server import RealtimePhysics
from hil_sim.world import World
from runtime.franka_driver.__main__ import parser, serve


def standalone(kind: str = "cube", seed: int = 0) -> MujocoBackend:
    """A world of its own, stepped in real time by a physics thread that stops on ``close()``."""
    world = World([kind])
    world.reset(kind, seed, randomise=False)
    physics = RealtimePhysics(world)
    physics.start()
    return MujocoBackend(world, physics.lock, on_close=physics.stop)


def main(argv: list[str] | None = None) -> int:
    return serve(parser("python -m hil_sim.driver", __doc__).parse_args(argv), standalone, "mujoco")


if __name__ == "__main__":
    sys.exit(main())
