"""hil_sim's real-time server: the MuJoCo world stepped at wall-clock speed, a simulated D455 publishing
depth over ZeroMQ, and the robot driver serving state and commands:

* physics (thread): steps the world in 5 ms chunks to keep simulated time = wall time, under one lock;
* driver (thread): ``runtime.franka_driver``'s ``DriverServer``, the same server the real robot gets, over
  ``hil_sim.driver_backend.MujocoBackend``;
* camera (its own process: rendering held the GIL long enough to stall the driver's 200 Hz state
  stream past the runtime's 100 ms staleness limit, measured): snapshots the pose at ``camera_hz``
  (``t_capture``), renders depth, publishes ``publish_delay_s`` after capture, as a real D455 delivers a
  frame some tens of ms after exposure.

Rendering at 848x480 with llvmpipe costs ~60 ms on these 2 cores (measured), more than a 10 Hz loop can
share, so the camera renders at ``render_scale`` (default 1/2: ~25 ms) and repeats pixels back to 848x480:
the wire format, stream size and preprocessing the runtime sees are the real ones, the detail is that of a
424x240 sensor (the policy sees 128x96 anyway).

``sensor="stereo"`` publishes the active-stereo model's depth instead (``hil_sim.stereo``: holes, noise;
its own working resolution). A frame takes longer to compute than a D455 takes to deliver one, so a frame
is stamped as captured ``publish_delay_s`` before it is ready, as the real sensor's latency; the scene it
shows is older than that by the rest of the compute time (reported as ``hidden_lag_ms``).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import zmq

from hil_sim.camera import to_millimetres
from hil_sim.driver_backend import MujocoBackend
from hil_sim.world import CAMERA, World
from runtime.franka_driver.server import DriverConfig, DriverServer
from runtime.protocol import DEFAULT_CAMERA, DEFAULT_ROBOT, Encoder
from runtime.transport import TransportError, bind

DEPTH_SCALE = 0.001  # uint16 millimetres, as a D455 reports with its default depth units
SENSORS = ("clean", "stereo")


@dataclass(frozen=True)
class SimConfig:
    """The simulated camera and robot served to a runtime."""

    camera: str = DEFAULT_CAMERA
    """Endpoint the depth frames are PUBlished on."""
    robot: str = DEFAULT_ROBOT
    """Driver state endpoint (commands on port + 1)."""
    camera_hz: float = 15.0
    """Depth frame rate. A D455 offers 5/15/30/60/90 fps at 848x480; 15 is what 2 shared cores sustain
    next to the runtime (30 would cost ~75 % of a core in rendering alone)."""
    render_scale: float = 0.5
    """Render size as a fraction of the 848x480 stream (1/n); pixels are repeated back up to 848x480."""
    publish_delay_s: float = 0.035
    """Capture -> publish delay of a frame (D4xx: exposure, on-chip depth, USB transfer ~ 30-40 ms)."""
    state_hz: float = 200.0
    """Driver state rate."""
    object_kind: str = "cube"
    seed: int = 0
    sensor: str = "clean"
    """Depth the camera publishes: ``clean`` (exact, rendered at ``render_scale``) or ``stereo`` (the
    active-stereo model with its fitted parameters)."""

    def __post_init__(self) -> None:
        if self.sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {', '.join(SENSORS)}, got {self.sensor!r}")
        if not 1.0 <= self.camera_hz <= 90.0:
            raise ValueError(f"camera_hz must be in [1, 90], got {self.camera_hz}")
        if not (0 < self.render_scale <= 1 and (1 / self.render_scale).is_integer()):
            raise ValueError(f"render_scale must be 1/n, got {self.render_scale}")
        if not 0 <= self.publish_delay_s < 1 / self.camera_hz:
            raise ValueError(f"publish_delay_s must be in [0, one camera period), got {self.publish_delay_s}")


class RealtimePhysics:
    """Steps ``world`` so simulated time follows the wall clock; ``lag_s``: how far it fell behind."""

    CHUNK_S = 0.005
    MAX_CATCH_UP_S = 0.05

    def __init__(self, world: World, *, on_step: Callable[[np.ndarray], None] | None = None) -> None:
        self.world = world
        self.lock = threading.Lock()
        self._on_step = on_step
        self.lag_s = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hil-physics", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        dt = self.world.model.opt.timestep
        start, sim_steps = time.monotonic(), 0
        while not self._stop.wait(self.CHUNK_S):
            due = int((time.monotonic() - start) / dt)
            n = due - sim_steps
            if n * dt > self.MAX_CATCH_UP_S:  # starved of CPU: drop the backlog instead of spiralling
                self.lag_s += n * dt - self.MAX_CATCH_UP_S
                sim_steps, n = due - int(self.MAX_CATCH_UP_S / dt), int(self.MAX_CATCH_UP_S / dt)
            if n > 0:
                with self.lock:
                    mujoco.mj_step(self.world.model, self.world.data, nstep=n)
                    qpos = self.world.data.qpos.copy()
                sim_steps += n
                if self._on_step is not None:
                    self._on_step(qpos)


class CameraPublisher:
    """The simulated D455, in a process of its own so rendering never holds the driver's GIL.

    It keeps a replica of the world: each frame copies the physics process's ``qpos`` from shared memory
    (``t_capture`` is that instant), renders depth, waits out the sensor delay and publishes. Faults can be
    injected from the parent (``stall``, ``drop``).
    """

    def __init__(self, config: SimConfig, nq: int) -> None:
        ctx = mp.get_context("spawn")  # no fork of a process that holds a GL context and zmq sockets
        self.qpos = ctx.Array("d", nq)
        self._published = ctx.Value("l", 0)
        self._render = ctx.Array("d", 3)  # total render seconds, frames rendered, total hidden lag seconds
        self._pause_until = ctx.Value("d", 0.0)
        self._drop = ctx.Value("l", 0)
        self._stop = ctx.Event()
        self._ready = ctx.Event()
        self._proc = ctx.Process(target=_camera_main, name="hil-camera", daemon=True,
                                 args=(config, self.qpos, self._published, self._render, self._pause_until,
                                       self._drop, self._stop, self._ready))

    def start(self, timeout_s: float = 60.0) -> None:
        self._proc.start()
        if not self._ready.wait(timeout_s):
            self.stop()
            raise RuntimeError(f"simulated camera did not start within {timeout_s} s")

    def stop(self) -> None:
        self._stop.set()
        self._proc.join(5.0)
        if self._proc.is_alive():
            self._proc.kill()

    def share(self, qpos: np.ndarray) -> None:
        """Called by the physics loop after each chunk: the pose the next frame will show."""
        with self.qpos.get_lock():
            self.qpos[:] = qpos

    def stall(self, seconds: float) -> None:
        """Publish nothing for ``seconds`` (frames are still captured and numbered, as a stuck USB link)."""
        self._pause_until.value = time.monotonic() + seconds

    def drop(self, frames: int) -> None:
        """Lose the next ``frames`` frames."""
        self._drop.value = frames

    @property
    def published(self) -> int:
        return self._published.value

    @property
    def render_ms_mean(self) -> float:
        total, n, _ = self._render[:]
        return 1e3 * total / n if n else float("nan")

    @property
    def hidden_lag_ms_mean(self) -> float:
        """Mean time by which a frame's scene is older than its capture stamp (compute past the delay)."""
        _, n, lag = self._render[:]
        return 1e3 * lag / n if n else float("nan")


def _camera_main(config: SimConfig, qpos, published, render, pause_until, drop, stop, ready) -> None:
    world = World([config.object_kind])
    world.reset(config.object_kind, config.seed, randomise=False)
    depth, close = _depth_source(config, world)
    pub = bind(zmq.Context.instance(), zmq.PUB, config.camera)
    enc = Encoder()
    period = 1.0 / config.camera_hz
    frame, next_t = 0, time.monotonic()
    ready.set()
    try:
        while not stop.wait(max(0.0, next_t - time.monotonic())):
            with qpos.get_lock():
                t_snapshot = time.monotonic()
                world.data.qpos[:] = qpos[:]
            mujoco.mj_forward(world.model, world.data)
            mm = depth()
            done = time.monotonic()
            t_capture = t_snapshot
            if config.sensor == "stereo":  # computes longer than a D455 delivers: stamp as its latency says
                t_capture = max(t_snapshot, done - config.publish_delay_s)
            render[:] = [render[0] + done - t_snapshot, render[1] + 1, render[2] + t_capture - t_snapshot]
            stop.wait(max(0.0, t_capture + config.publish_delay_s - time.monotonic()))
            if drop.value > 0:
                drop.value -= 1
            elif time.monotonic() >= pause_until.value:
                frames = enc.depth(mm, t_capture=t_capture, frame_number=frame, depth_scale=DEPTH_SCALE)
                with contextlib.suppress(zmq.Again):
                    pub.send_multipart(frames, flags=zmq.NOBLOCK, copy=False)
                    published.value += 1
            frame += 1
            next_t += period
            if next_t < time.monotonic():  # fell behind: keep the phase, skip the missed slots
                next_t += period * np.ceil((time.monotonic() - next_t) / period)
    finally:
        pub.close(linger=0)
        close()


def _depth_source(config: SimConfig, world: World) -> tuple[Callable[[], np.ndarray], Callable[[], None]]:
    """The camera's frame maker (uint16 mm at the stream size, from the world's current state) and its
    close function."""
    if config.sensor == "stereo":
        from hil_sim.stereo import StereoSensor

        sensor = StereoSensor()
        sensor.reset(world, config.seed)
        return lambda: sensor.stream(world), sensor.close
    intr, scale = world.intr, config.render_scale
    renderer = mujoco.Renderer(world.model, round(intr.height * scale), round(intr.width * scale))
    renderer.enable_depth_rendering()
    repeat = round(1 / scale)

    def exact() -> np.ndarray:
        renderer.update_scene(world.data, CAMERA)
        mm = to_millimetres(renderer.render(), intr)
        return np.repeat(np.repeat(mm, repeat, axis=0), repeat, axis=1) if repeat > 1 else mm

    return exact, renderer.close


_REBIND_S = 2.0
"""How long a driver restart waits for its port to be released."""

class CommandLog:
    """Receipts of the commands the driver executed, for the benchmark's report: the newest ``capacity`` of
    them in a fixed ring of (seq, t_receive, deadline). A list of every receipt grew ~12 MB an hour in the
    soak; this holds 2^18 receipts (7 h at 10 Hz) in 6 MB, allocated once. ``len`` counts all of them."""

    FIELDS = ("seq", "t_receive", "deadline")

    def __init__(self, capacity: int = 1 << 18) -> None:
        self._ring = np.zeros((capacity, len(self.FIELDS)))
        self._count = 0
        self._lock = threading.Lock()

    def append(self, receipt: dict[str, Any]) -> None:
        with self._lock:
            self._ring[self._count % len(self._ring)] = [receipt[f] for f in self.FIELDS]
            self._count += 1

    def __len__(self) -> int:
        return self._count

    def __iter__(self) -> Iterator[dict[str, Any]]:
        """The retained receipts, oldest first, as dicts (``seq`` an int)."""
        with self._lock:
            n, cap = self._count, len(self._ring)
            rows = np.roll(self._ring, -(n % cap), axis=0) if n > cap else self._ring[:n].copy()
        for seq, t_receive, deadline in rows:
            yield {"seq": int(seq), "t_receive": float(t_receive), "deadline": float(deadline)}


    def since(self, start: int) -> list[dict[str, Any]]:
        """The retained receipts from the ``start``-th on (counting every receipt appended): one episode's."""
        receipts = list(self)
        return receipts[max(0, start - (len(self) - len(receipts))):]


class SimServer:
    """World + physics + camera + driver, as a context manager. ``commands`` holds what the driver took."""

    def __init__(self, config: SimConfig = SimConfig(), *, world: World | None = None) -> None:
        self.config = config
        self.world = world or World([config.object_kind])
        self.world.reset(config.object_kind, config.seed, randomise=False)
        self.commands = CommandLog()
        self.camera = CameraPublisher(config, self.world.model.nq)
        self.camera.share(self.world.data.qpos)
        self.physics = RealtimePhysics(self.world, on_step=self.camera.share)
        self._ctx = zmq.Context()
        self._driver_stop = threading.Event()
        self._driver_thread: threading.Thread | None = None
        self.driver: DriverServer | None = None
        self.driver_error: BaseException | None = None

    def __enter__(self) -> SimServer:
        self.camera.start()
        self.physics.start()
        self.start_driver()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_driver()
        self.camera.stop()
        self.physics.stop()
        self.world.close()
        self._ctx.term()

    def start_driver(self) -> None:
        """Start (or restart) the driver on the configured address. Right after ``stop_driver`` the port can
        still be held for a moment: ZeroMQ closes the old sockets on its I/O thread, after ``close`` returns
        (a restart failed with "Address already in use" within 4 tries), so a bind is retried for a while."""
        config = DriverConfig(bind=self.config.robot, state_hz=self.config.state_hz)
        deadline = time.monotonic() + _REBIND_S
        while True:
            self.driver = DriverServer(MujocoBackend(self.world, self.physics.lock), config,
                                       on_command=self.commands.append, context=self._ctx)
            try:
                self.driver.__enter__()
                break
            except TransportError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.02)
        self._driver_stop = threading.Event()
        self._driver_thread = threading.Thread(target=self._serve, name="hil-driver", daemon=True)
        self._driver_thread.start()

    def stop_driver(self) -> None:
        """Stop the driver: its sockets close and the arm is left holding."""
        if self._driver_thread is None:
            return
        self._driver_stop.set()
        self._driver_thread.join(2.0)
        self.driver.__exit__(None, None, None)
        self._driver_thread = None

    def _serve(self) -> None:
        try:
            self.driver.serve(self._driver_stop)
        except BaseException as exc:  # reported by the benchmark; the driver has already announced it
            self.driver_error = exc
