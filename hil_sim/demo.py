"""``python -m hil_sim.demo`` (``make demo``): the shipped student grasping in the hardware-in-the-loop rig.

Each episode places the object (same kind, seeds ``--seed``, ``--seed`` + 1, ...), restarts the driver and
starts the real ``runtime`` process against the simulated D455 and the MuJoCo arm, as on the robot. The
episode ends when the object has been held at the lift target for ``HOLD_S`` (success: the runtime is
stopped with SIGINT and holds the object up) or after ``--seconds``. One progress line per episode, then a
summary: grasps, successes, latency, late ticks, the runtime's and driver's events, and the files written
under ``--out``: an animated GIF of one episode rendered from the simulator (the first success, else the
first grasp, else the first episode), the latency plot, demo.json, and each episode's ticks and log.

Success is ``trainer.sim.env.GraspEnv``'s criterion, read off the live world here (the deploy side does not
import the trainer): the object held by both fingers, lifted, within ``TARGET_TOL_M`` of the point
``LIFT_M`` above the table over its start, for ``HOLD_S``. "Grasped" = held off the table at any moment.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil_sim import report
from hil_sim.__main__ import REPO, BenchmarkError, Run, pin_cores, resolve_model, run_runtime, runtime_ticks
from hil_sim.objects import resolve
from runtime.protocol import DEFAULT_CAMERA, DEFAULT_ROBOT

LIFT_M = 0.40
TARGET_TOL_M = 0.04
HOLD_S = 0.5
"""GraspEnv's lift_height_m, success_tol_m and hold_steps (5 at 10 Hz)."""
CLEARANCE_M = 0.02
"""Lifted: the object's centre more than its half height plus this above the table (GraspEnv's test)."""
GIF_SIZE = (320, 240)
_STATUS = re.compile(r"^runtime: status (\S+): (\S*)")


@dataclass
class Judge:
    """Watches the live world while the runtime drives it: grasp, success, and the poses for the video."""

    world: Any
    lock: threading.Lock
    target: np.ndarray
    grasped: bool = False
    success: bool = False
    poses: list[np.ndarray] = field(default_factory=list)
    _at_target_since: float | None = None

    def __call__(self) -> bool:
        """One look at the world (every ``WATCH_S``); True once the episode has succeeded."""
        from hil_sim.world import TABLE_Z

        with self.lock:
            left, right = self.world.finger_contacts()
            position = self.world.object_pose()[0]
            half_height = self.world.object_extent()[2]
            self.poses.append(self.world.data.qpos.copy())
        held = bool(left and right and position[2] > TABLE_Z + half_height + CLEARANCE_M)
        self.grasped |= held
        now = time.monotonic()
        if not (held and float(np.linalg.norm(position - self.target)) < TARGET_TOL_M):
            self._at_target_since = None
        elif self._at_target_since is None:
            self._at_target_since = now
        self.success |= self._at_target_since is not None and now - self._at_target_since >= HOLD_S
        return self.success


@dataclass
class Episode:
    number: int
    seed: int
    judge: Judge
    seconds: float
    runtime_exit: int
    doc: dict[str, Any]
    events: Counter
    ticks: list[dict[str, Any]]
    commands: list[dict[str, Any]]

    def line(self, total: int) -> str:
        outcome = "SUCCESS" if self.judge.success else "grasped, not lifted to the target" if (
            self.judge.grasped) else "no grasp"
        lat = self.doc["latency_ms"]
        return (f"episode {self.number}/{total} (seed {self.seed}): {outcome:<33} {self.seconds:5.1f} s, "
                f"{self.doc['ticks']} ticks, {self.doc['late_ticks']} late, latency p50 {lat['p50']:.1f} / "
                f"p99 {lat['p99']:.1f} ms, events: {_events(self.events)}")


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m hil_sim.demo", description=__doc__.split("\n\n")[0],
                                epilog=__doc__.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=4, help="episodes to run (default %(default)s)")
    p.add_argument("--kind", default="cube", help="object kind (default %(default)s)")
    p.add_argument("--seed", type=int, default=10_000, help="seed of the first episode's placement")
    p.add_argument("--seconds", type=float, default=15.0,
                   help="longest episode, s (default %(default)s: GraspEnv's 150 steps at 10 Hz)")
    p.add_argument("--rate", type=float, default=10.0, help="control rate, Hz (default %(default)s)")
    p.add_argument("--model", type=Path, help="student.onnx (default models/student.onnx)")
    p.add_argument("--out", type=Path, default=REPO / "runs" / "demo",
                   help="output folder (default runs/demo)")
    p.add_argument("--camera", default=DEFAULT_CAMERA, help="depth PUB endpoint (default %(default)s)")
    p.add_argument("--robot", default=DEFAULT_ROBOT, help="driver state endpoint (default %(default)s)")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes must be at least 1, got {args.episodes}")
    return args


def run_episode(sim: Any, run: Run, number: int, seed: int, kind: str) -> Episode:
    """Place the object, restart the driver (fresh state, as after a robot reset), run one runtime."""
    sim.stop_driver()
    with sim.physics.lock:
        sim.world.reset(kind, seed, randomise=False)
        start = sim.world.object_pose()[0]
    sim.start_driver()
    judge = Judge(sim.world, sim.physics.lock, np.array([start[0], start[1], start[2] + LIFT_M]))
    first_command = len(sim.commands)
    began = time.monotonic()
    code, usage = run_runtime(run, watch=judge)
    seconds = time.monotonic() - began
    ticks, log = runtime_ticks(run, code)
    commands = sim.commands.since(first_command)
    doc = report.build(ticks, commands, rate_hz=run.rate_hz, usage=usage)
    events = runtime_events("\n".join(log))
    return Episode(number, seed, judge, seconds, code, doc, events, ticks, commands)


def runtime_events(log: str) -> Counter:
    """The runtime's status reports by code, the driver's faults as ``driver <code>``; ends of faults
    (``*_cleared``, the driver's "fault cleared") are not counted as events."""
    events: Counter = Counter()
    for line in log.splitlines():
        if m := _STATUS.match(line):
            code, first_word = m.groups()
            if code == "driver":
                code = None if first_word == "fault" else f"driver {first_word.rstrip(':')}"
            if code and not code.endswith("_cleared"):
                events[code] += 1
    return events


def _events(events: Counter) -> str:
    return ", ".join(f"{code} x{n}" for code, n in sorted(events.items())) or "none"


def render_gif(model: Any, episode: Episode, path: Path, kind: str) -> None:
    """The episode's recorded poses rendered in colour from a viewer's camera, one frame per look."""
    import mujoco
    from PIL import Image, ImageDraw

    from hil_sim.world import TABLE_Z

    data = mujoco.MjData(model)
    view = mujoco.MjvCamera()
    view.lookat[:] = (0.45, 0.0, TABLE_Z + 0.15)
    view.distance, view.azimuth, view.elevation = 1.5, 135.0, -25.0
    width, height = GIF_SIZE
    frames = []
    with mujoco.Renderer(model, height, width) as renderer:
        for i, qpos in enumerate(episode.judge.poses):
            data.qpos[:] = qpos
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, view)
            image = Image.fromarray(renderer.render())
            ImageDraw.Draw(image).text((6, 6), f"episode {episode.number}, {kind}, t = {i * 0.1:.1f} s",
                                       fill=(255, 255, 255))
            frames.append(image.quantize(colors=128))
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=100, loop=0)


def showcase(episodes: list[Episode]) -> Episode:
    """The first success, else the first grasp, else the first episode."""
    return next((e for e in episodes if e.judge.success), None) or next(
        (e for e in episodes if e.judge.grasped), episodes[0])


def latency_plot(episodes: list[Episode], path: Path, rate_hz: float, camera_fps: float) -> dict[str, Any]:
    """One plot and one report over every episode's ticks (command numbers restart with each runtime,
    so each is keyed by its episode)."""
    ticks = [dict(t, cmd_seq=(e.number, t["cmd_seq"])) for e in episodes for t in e.ticks]
    commands = [dict(c, seq=(e.number, c["seq"])) for e in episodes for c in e.commands]
    report.histogram(ticks, commands, path, rate_hz=rate_hz, camera_fps=camera_fps,
                     title=f"make demo: {len(episodes)} episodes at {rate_hz:g} Hz, {len(ticks)} ticks")
    usage = report.Usage(0.0, 0.0)
    return report.build(ticks, commands, rate_hz=rate_hz, usage=usage)


def demo(args: argparse.Namespace) -> tuple[list[Episode], dict[str, Any]]:
    from hil_sim.server import SimConfig, SimServer  # heavy (MuJoCo, GL): after argument checks

    model = resolve_model(args.model)
    resolve(args.kind)
    pin_cores()
    runs = [Run(args.seconds, args.rate, model, args.out / f"episode{i + 1}", args.camera, args.robot)
            for i in range(args.episodes)]  # settings checked before the rig starts
    episodes: list[Episode] = []
    print(f"demo: {args.episodes} episodes of {args.kind!r}: {model} drives the simulated Panda at "
          f"{args.rate:g} Hz through the real runtime process and driver", flush=True)
    with SimServer(SimConfig(args.camera, args.robot, object_kind=args.kind, seed=args.seed)) as sim:
        t0, published0 = time.monotonic(), sim.camera.published
        for i, run in enumerate(runs):
            run.report_dir.mkdir(parents=True, exist_ok=True)
            episodes.append(run_episode(sim, run, i + 1, args.seed + i, args.kind))
            print(episodes[-1].line(args.episodes), flush=True)
        camera_fps = (sim.camera.published - published0) / (time.monotonic() - t0)
        shown = showcase(episodes)
        render_gif(sim.world.model, shown, args.out / "episode.gif", args.kind)
    overall = latency_plot(episodes, args.out / "latency.png", args.rate, camera_fps)
    return episodes, overall


def summary(episodes: list[Episode], overall: dict[str, Any], out: Path) -> dict[str, Any]:
    shown = showcase(episodes)
    events = sum((e.events for e in episodes), Counter())
    successes = sum(e.judge.success for e in episodes)
    return {"episodes": len(episodes), "grasped": sum(e.judge.grasped for e in episodes),
            "successes": successes, "success_rate": successes / len(episodes),
            "latency_ms": overall["latency_ms"], "ticks": overall["ticks"],
            "late_ticks": overall["late_ticks"], "events": dict(events),
            "runtime_exits": [e.runtime_exit for e in episodes], "video": str(out / "episode.gif"),
            "video_episode": shown.number, "plot": str(out / "latency.png"),
            "per_episode": [{"seed": e.seed, "grasped": e.judge.grasped, "success": e.judge.success,
                             "seconds": round(e.seconds, 2), "report": e.doc} for e in episodes]}


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    try:
        episodes, overall = demo(args)
    except (BenchmarkError, report.ReportError, ValueError) as exc:
        print(f"hil_sim.demo: {exc}", file=sys.stderr)
        return 2
    doc = summary(episodes, overall, args.out)
    (args.out / "demo.json").write_text(json.dumps(doc, indent=2) + "\n")
    lat = doc["latency_ms"]
    print(f"grasps    {doc['grasped']} of {doc['episodes']} episodes, success {doc['successes']} "
          f"({doc['success_rate']:.0%}; measured over 180 episodes: the README's first table)\n"
          f"latency   frame received -> command at driver p50 {lat['p50']:.1f} ms, p99 {lat['p99']:.1f} ms "
          f"(goal {report.LATENCY_GOAL_MS:g}); {doc['ticks']} ticks, {doc['late_ticks']} late\n"
          f"events    {_events(Counter(doc['events']))}\n"
          f"video     {doc['video']} (episode {doc['video_episode']})\n"
          f"plot      {doc['plot']}\n"
          f"summary   {args.out / 'demo.json'}")
    failed = [e for e in episodes if e.runtime_exit != 0]
    for e in failed:
        print(f"hil_sim.demo: episode {e.number}: runtime exited with {e.runtime_exit} "
              f"(see {args.out / f'episode{e.number}' / 'runtime.log'})", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
