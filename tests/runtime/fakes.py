"""Stand-ins for the camera, the robot link and the policy (on a virtual clock, for loop tests) and a
loopback camera + driver pair (real time, for tests of the `runtime` process)."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import zmq

from runtime.cameras.base import Frame
from runtime.policy import NanActionError
from runtime.protocol import DOF, Encoder, decode, robot_endpoints
from tests.runtime.handmade import DELTA, metadata

READY_Q = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


class VirtualClock:
    """Test time: it moves only when a fake waits or works, so loop timing tests are exact and instant."""

    def __init__(self, start: float = 1000.0) -> None:
        self.t = start
        self.stop_at: float | None = None
        self.stop: threading.Event | None = None

    def __call__(self) -> float:
        if self.stop is not None and self.stop_at is not None and self.t >= self.stop_at:
            self.stop.set()  # a signal arriving at a chosen instant
        return self.t

    def sleep(self, seconds: float) -> None:
        if seconds > 0:  # always move: a wait shorter than float resolution must still end
            self.t = max(self.t + seconds, float(np.nextafter(self.t, np.inf)))


class FakeCamera:
    """Frames captured at start + i * period and received ``delay`` later; silence after ``stop_after``
    frames; ``age`` stamps captures that much earlier (stale frames)."""

    def __init__(self, clock: VirtualClock, period_s: float, *, stop_after: int | None = None,
                 delay: float = 0.001, age: float = 0.0, size: tuple[int, int] = (480, 848)) -> None:
        self.clock, self.name, self.period_s = clock, "fake", period_s
        self.stop_after, self.delay, self.age = stop_after, delay, age
        self.depth = np.full(size, 900, np.uint16)
        self.start = clock() + 0.0123  # an arbitrary phase against the loop's start
        self.next = 0

    def arrival(self, i: int) -> float:
        return self.start + i * self.period_s + self.delay

    def poll(self, timeout_s: float) -> Frame | None:
        now = self.clock()
        silent = self.stop_after is not None and self.next >= self.stop_after
        if silent or self.arrival(self.next) > now + timeout_s:
            self.clock.sleep(timeout_s)
            return None
        self.clock.t = max(now, self.arrival(self.next))
        newest = max(self.next, int((self.clock() - self.start - self.delay) / self.period_s))
        if self.stop_after is not None:
            newest = min(newest, self.stop_after - 1)
        self.next = newest + 1
        t_capture = self.start + newest * self.period_s
        return Frame(self.depth, 0.001, t_capture - self.age, self.clock(), newest)

    def close(self) -> None:
        pass


class FakeRobot:
    """Quacks like RobotLink: a state that is always fresh (until ``stale_after``) and a list of commands."""

    def __init__(self, clock: VirtualClock, q: np.ndarray = READY_Q, gripper: float = 0.08,
                 stale_after: float | None = None) -> None:
        self.clock, self.q, self.gripper, self.stale_after = clock, np.array(q, float), gripper, stale_after
        self.commands: list[dict] = []
        self.latest: dict | None = None
        self.address = "fake"
        self.tag = "fake-runtime"
        self.controller = ""
        """The session tag states carry: "" (none yet), ``tag`` or another's (the arm taken)."""
        self.rejected = 0

    def poll(self, timeout_s: float = 0.0) -> dict | None:
        if self.stale_after is None or self.clock() < self.stale_after:
            self.latest = {"q": list(self.q), "gripper": self.gripper, "t_capture": self.clock(), "fault": "",
                           "controller": self.controller}
        return self.latest

    def command(self, q_target, gripper, *, validity_s, t_capture) -> int:
        now = self.clock()
        self.commands.append({"q_target": np.array(q_target), "gripper": gripper, "t_send": now,
                              "deadline": now + validity_s, "t_capture": t_capture})
        return len(self.commands) - 1


class FakePolicy:
    """Quacks like Policy: action i moves joint 0 by (i + 1) * DELTA and the others by DELTA; each call takes
    ``delay`` of the clock's time; NaN on the chosen (1-based) calls."""

    def __init__(self, clock: VirtualClock, *, delay: float = 0.005,
                 nan_calls: set[int] | frozenset = frozenset(), **meta) -> None:
        # joint 0 encodes the action index, up to 16 * DELTA: an action scale that bounds it (output check)
        self.clock, self.metadata = clock, metadata(**{"action_scale": 0.1, **meta})
        self.delay, self.nan_calls = delay, nan_calls
        self.calls = 0
        self.states: list[np.ndarray] = []
        self.depths: list[np.ndarray] = []

    def warmup(self, runs: int = 5) -> list[float]:
        return [self.delay] * runs

    def __call__(self, depth: np.ndarray, state: np.ndarray) -> np.ndarray:
        assert depth.shape == tuple(self.metadata.input_shapes()["depth"][1:]) and state.shape == (DOF + 1,)
        self.calls += 1
        self.states.append(state.copy())
        self.depths.append(depth.copy())
        self.clock.sleep(self.delay)
        if self.calls in self.nan_calls:
            raise NanActionError("fake produced NaN")
        actions = np.full((self.metadata.action_horizon, DOF + 1), DELTA, np.float32)
        actions[:, 0] = DELTA * np.arange(1, self.metadata.action_horizon + 1)  # joint 0 encodes the index
        actions[:, DOF] = 1.0
        return actions


def free_port_pair() -> int:
    """A loopback port P with P + 1 also free (robot state + command)."""
    while True:
        with socket.socket() as a, socket.socket() as b:
            a.bind(("127.0.0.1", 0))
            port = a.getsockname()[1]
            try:
                b.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
            return port


def free_addresses() -> tuple[str, str]:
    """Loopback camera and robot endpoints that do not collide: the robot takes two ports, and two separate
    ``free_port_pair`` calls may hand out the same ones (nothing holds them in between)."""
    robot = camera = free_port_pair()
    while camera in (robot, robot + 1):
        camera = free_port_pair()
    return f"tcp://127.0.0.1:{camera}", f"tcp://127.0.0.1:{robot}"


class FakeWorld:
    """Camera PUB (848x480 at ``fps`` until ``camera_stop`` is set) and driver PUB state / PULL commands."""

    def __init__(self, fps: float) -> None:
        self.ctx = zmq.Context()
        self.camera, self.robot = free_addresses()
        self.fps = fps
        self.commands: list[dict] = []
        self.stop, self.camera_stop = threading.Event(), threading.Event()
        self.threads = [threading.Thread(target=f, daemon=True) for f in (self._camera, self._driver)]

    def __enter__(self):
        for t in self.threads:
            t.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        for t in self.threads:
            t.join(2)
        self.ctx.destroy(linger=0)  # never hang on a socket a failed thread left open

    def _camera(self) -> None:
        pub, enc = self.ctx.socket(zmq.PUB), Encoder()
        pub.linger = 0
        pub.bind(self.camera)
        depth = np.full((480, 848), 900, np.uint16)
        start, i = time.monotonic(), 0
        while not self.stop.is_set():
            time.sleep(max(0.0, start + i / self.fps - time.monotonic()))
            if not self.camera_stop.is_set():
                pub.send_multipart(enc.depth(depth, t_capture=time.monotonic(), frame_number=i,
                                             depth_scale=0.001))
            i += 1
        pub.close()

    def _driver(self) -> None:
        state_ep, command_ep = robot_endpoints(self.robot)
        pub, pull, enc = self.ctx.socket(zmq.PUB), self.ctx.socket(zmq.PULL), Encoder()
        pub.linger = pull.linger = 0
        pub.bind(state_ep)
        pull.bind(command_ep)
        while not self.stop.is_set():
            pub.send_multipart(enc.encode("state", t_capture=time.monotonic(), q=list(READY_Q), dq=[0.0] * 7,
                                          gripper=0.08, holding=False, fault="", controller=""))
            if pull.poll(5):
                while pull.poll(0):
                    msg = decode(pull.recv_multipart())
                    self.commands.append(msg.header | {"t_receive": time.monotonic()})
        pub.close()
        pull.close()

    def wait_commands(self, n: int, timeout: float = 20.0) -> None:
        end = time.monotonic() + timeout
        while len(self.commands) < n:
            assert time.monotonic() < end, f"only {len(self.commands)} commands arrived"
            time.sleep(0.02)
