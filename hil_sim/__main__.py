"""``python -m hil_sim [--seconds S] [--rate HZ] [--model PATH] [--report DIR] [--sensor NAME]``: the HIL
latency benchmark.

Starts the simulated camera + robot (hil_sim.server), starts the real ``runtime`` as a separate process
against them, runs for S seconds at HZ with every process pinned to the machine's first two cores, and
writes DIR/report.json, DIR/latency.png, DIR/ticks.jsonl, DIR/runtime.log. Exit status 0 only when the
rate was held: no late tick (or no more than ``--late-share`` of them) and the achieved rate within 1 % of
HZ. The report counts the cores' time the hypervisor took meanwhile (``host_steal_percent``): on a virtual
machine no priority inside it keeps the loop's core. ``--sensor stereo`` makes the camera
publish the active-stereo model's depth (``hil_sim.stereo``), by default at 5 Hz.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hil_sim import report
from runtime.preprocess import RESTORE_METHODS
from runtime.protocol import DEFAULT_CAMERA, DEFAULT_ROBOT

REPO = Path(__file__).resolve().parents[1]
TRAINED_MODEL = REPO / "models" / "student.onnx"
UNTRAINED_MODEL = REPO / "runs" / "hil" / "untrained_student.onnx"
STARTUP_GRACE_S = 90.0
WATCH_S = 0.1
STEREO_CAMERA_HZ = 5.0
"""The lowest D455 frame rate (5/15/30 fps): a stereo frame costs ~150-350 ms on 2 shared cores
(docs/stereo.md), so under load the camera falls below it and skips slots."""


class BenchmarkError(RuntimeError):
    """The benchmark could not run (no model, runtime died, no metrics)."""


@dataclass(frozen=True)
class Run:
    """One benchmark run's settings."""

    seconds: float
    rate_hz: float
    model: Path
    report_dir: Path
    camera: str = DEFAULT_CAMERA
    robot: str = DEFAULT_ROBOT
    camera_hz: float = 15.0
    sensor: str = "clean"
    restore: str = "none"
    late_share: float = 0.0

    def __post_init__(self) -> None:
        for flag, value in (("--rate", self.rate_hz), ("--seconds", self.seconds)):
            if not value > 0:  # 0 Hz would "run" and report NOT HELD against a target of 0
                raise ValueError(f"{flag} must be positive, got {value:g}")
        if not 0.0 <= self.late_share < 1.0:
            raise ValueError(f"--late-share must be in [0, 1), got {self.late_share:g}")


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m hil_sim", description=__doc__.split("\n\n")[0],
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--seconds", type=float, default=60.0, help="length of the measured run (default 60)")
    p.add_argument("--rate", type=float, default=10.0, help="control rate of the runtime, Hz (default 10)")
    p.add_argument("--model", type=Path, help="student.onnx (default: models/student.onnx if it exists, else "
                   "an UNTRAINED student built by the export code, announced as such)")
    p.add_argument("--report", type=Path, default=REPO / "runs" / "hil",
                   help="report folder (default runs/hil)")
    p.add_argument("--camera", default=DEFAULT_CAMERA, help="depth PUB endpoint (default %(default)s)")
    p.add_argument("--robot", default=DEFAULT_ROBOT, help="driver state endpoint (default %(default)s)")
    p.add_argument("--camera-hz", type=float,
                   help=f"simulated D455 frame rate (default 15; {STEREO_CAMERA_HZ:g} with --sensor stereo)")
    p.add_argument("--sensor", choices=("clean", "stereo"), default="clean",
                   help="depth the camera publishes: exact (clean) or the active-stereo model")
    p.add_argument("--restore", choices=RESTORE_METHODS, default="none",
                   help="the runtime's hole restoration (runtime --restore; default none)")
    p.add_argument("--late-share", type=float, default=0.0,
                   help="share of ticks that may miss their deadline in a held rate (default 0: none may)")
    args = p.parse_args(argv)
    if args.camera_hz is None:
        args.camera_hz = STEREO_CAMERA_HZ if args.sensor == "stereo" else 15.0
    return args


def resolve_model(model: Path | None) -> Path:
    if model is not None:
        if not model.is_file():
            raise BenchmarkError(f"--model {model} does not exist")
        from runtime.policy import Policy, PolicyError  # onnxruntime: only to vet a file the user names

        try:  # here, or the runtime process fails on it with its reason only in its log
            Policy(model)
        except PolicyError as exc:
            raise BenchmarkError(f"--model {exc}") from None
        return model
    if TRAINED_MODEL.is_file():
        return TRAINED_MODEL
    print("hil_sim: WARNING no models/student.onnx: benchmarking an UNTRAINED student (random weights, "
          "full-size graph). Latency figures are valid; its actions are not a policy.", file=sys.stderr)
    if not UNTRAINED_MODEL.is_file():
        build_untrained(UNTRAINED_MODEL)
    return UNTRAINED_MODEL


def build_untrained(out: Path) -> None:
    """The export engineer's CLI path: ``trainer student init`` then ``python -m export``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    ckpt = out.with_suffix(".pt")
    for cmd in ([sys.executable, "-m", "trainer", "student", "init", "--out", str(ckpt)],
                [sys.executable, "-m", "export", str(ckpt), "--ddim-steps", "4", "--out", str(out)]):
        done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            raise BenchmarkError(f"building the untrained student failed: {' '.join(cmd[1:])}: "
                                 f"{done.stderr.strip().splitlines()[-1:]}")


def pin_cores() -> set[int]:
    """The first two cores of this process's affinity; this process and its children stay on them."""
    cores = set(sorted(os.sched_getaffinity(0))[:2])
    os.sched_setaffinity(0, cores)
    return cores


def host_steal_s() -> float | None:
    """Seconds of the cores' time the hypervisor took since boot (``/proc/stat``), None where unknown."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")  # cpu user nice system idle iowait irq softirq steal
    except (OSError, IndexError, ValueError):
        return None


def run_runtime(run: Run, watch: Callable[[], bool] | None = None) -> tuple[int, report.Usage]:
    """Run the real runtime process to completion; its exit code and resource use. ``watch`` (the demo's
    grasp judge) is called every ``WATCH_S`` while it runs; once it returns True the runtime is stopped as
    an operator would stop it, with SIGINT: it commands hold and exits 0."""
    cmd = [sys.executable, "-m", "runtime", "--model", str(run.model), "--camera", f"hil:{run.camera}",
           "--robot", run.robot, "--rate", str(run.rate_hz), "--seconds", str(run.seconds),
           "--metrics", str(run.report_dir / "ticks.jsonl"), "--restore", run.restore]
    path = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    env = dict(os.environ, PYTHONPATH=path)
    with open(run.report_dir / "runtime.log", "w") as log:
        start = time.monotonic()
        # The child inherits this process's pinning to ``cores``.
        proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
        deadline = start + run.seconds + STARTUP_GRACE_S
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            if watch is not None and watch():
                proc.send_signal(signal.SIGINT)
                watch = None
            time.sleep(WATCH_S)
        wall = time.monotonic() - start
    proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: keep Popen from waiting again
    cpu = 100.0 * (usage.ru_utime + usage.ru_stime) / wall
    return proc.returncode, report.Usage(cpu_percent=cpu, rss_mb=usage.ru_maxrss / 1024.0)


def runtime_ticks(run: Run, code: int) -> tuple[list, list[str]]:
    """The ticks a finished runtime recorded and its log's lines; a runtime that exited before its first tick
    is a ``BenchmarkError`` carrying its last words (its reason is in its log, not in the missing metrics)."""
    log = (run.report_dir / "runtime.log").read_text().strip().splitlines()
    try:
        return report.load_ticks(run.report_dir / "ticks.jsonl"), log
    except report.ReportError as exc:
        raise BenchmarkError(f"runtime exited with {code} before a tick: {' | '.join(log[-3:])}") from exc


def benchmark(run: Run) -> dict:
    from hil_sim.server import SimConfig, SimServer  # heavy (MuJoCo, GL): after argument checks

    cores = pin_cores()
    run.report_dir.mkdir(parents=True, exist_ok=True)
    config = SimConfig(camera=run.camera, robot=run.robot, camera_hz=run.camera_hz, sensor=run.sensor)
    with SimServer(config) as sim:
        t0, steps0, steal0 = time.monotonic(), sim.driver.steps, host_steal_s()
        code, usage = run_runtime(run)
        elapsed, steal1 = time.monotonic() - t0, host_steal_s()
        sim_stats = {"camera_fps": round(sim.camera.published / elapsed, 2),
                     "render_ms_mean": round(sim.camera.render_ms_mean, 2),
                     "hidden_lag_ms_mean": round(sim.camera.hidden_lag_ms_mean, 2), "sensor": run.sensor,
                     "restore": run.restore,
                     "state_hz": round((sim.driver.steps - steps0) / elapsed, 1),
                     "physics_lag_s": round(sim.physics.lag_s, 3),
                     "driver_error": repr(sim.driver_error) if sim.driver_error else None}
        commands = list(sim.commands)
    ticks, log = runtime_ticks(run, code)
    doc = report.build(ticks, commands, rate_hz=run.rate_hz, usage=usage, late_share=run.late_share)
    cores_s = elapsed * os.cpu_count()
    steal = None if None in (steal0, steal1) else round(100 * (steal1 - steal0) / cores_s, 2)
    doc.update(runtime_exit=code, runtime_last_words=log[-2:], model=str(run.model), cores=sorted(cores),
               sim=sim_stats, load_avg=os.getloadavg(), host_steal_percent=steal)
    (run.report_dir / "report.json").write_text(json.dumps(doc, indent=2) + "\n")
    report.histogram(ticks, commands, run.report_dir / "latency.png",
                     title=f"hil_sim: {run.rate_hz:g} Hz for {run.seconds:g} s, {doc['ticks']} ticks",
                     rate_hz=run.rate_hz, camera_fps=sim_stats["camera_fps"])
    return doc


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    try:
        run = Run(args.seconds, args.rate, resolve_model(args.model), args.report, args.camera, args.robot,
                  args.camera_hz, args.sensor, args.restore, args.late_share)
        doc = benchmark(run)
    except (BenchmarkError, report.ReportError, ValueError) as exc:
        print(f"hil_sim: {exc}", file=sys.stderr)
        return 2
    print(report.table(doc))
    print(f"sim: {doc['sim']}; load {doc['load_avg']}; report: {run.report_dir / 'report.json'}")
    if doc["runtime_exit"] != 0:
        print(f"hil_sim: runtime exited with {doc['runtime_exit']}: {' | '.join(doc['runtime_last_words'])}",
              file=sys.stderr)
    return 0 if report.rate_held(doc) and doc["runtime_exit"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
