"""``runtime``: run student.onnx on live depth and command the robot at a fixed rate.

Exit status: 0 clean stop (SIGINT/SIGTERM, --seconds reached, recording ended); 2 bad model or arguments;
3 camera failed, stalled or sending unusable frames; 4 robot state lost or the arm controlled by another
session; 5 policy kept producing non-finite actions; 6 policy output a joint delta beyond its bound. Every
exit after the loop has started leaves the arm with a hold command.
"""

from __future__ import annotations

import argparse
import sys
from contextlib import ExitStack, closing

from runtime.cameras import open_camera
from runtime.cameras.base import CameraError
from runtime.loop import EXIT_CAMERA, ControlLoop, LoopConfig, RobotLink
from runtime.policy import Policy, PolicyError, SessionConfig
from runtime.preprocess import RESTORE_METHODS
from runtime.protocol import DEFAULT_CAMERA, DEFAULT_ROBOT
from runtime.realtime import announce_priority, stop_on_signals
from runtime.transport import CurveKeys, TransportError

EXIT_USAGE = 2


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="runtime", description=__doc__.split("\n\n")[0],
                                epilog=__doc__.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, help="student.onnx written by `python -m export`")
    p.add_argument("--camera", required=True, metavar="d455|hil[:ADDR]|replay:PATH",
                   help="d455 (optionally d455:SERIAL or d455:FILE.bag for playback), hil (depth messages "
                        f"over ZeroMQ, default {DEFAULT_CAMERA}) or replay:PATH (.npz or folder of .npy)")
    p.add_argument("--robot", default=DEFAULT_ROBOT, metavar="ADDR",
                   help="franka_driver state endpoint tcp://HOST:PORT; commands go to PORT+1 "
                        "(default %(default)s)")
    p.add_argument("--rate", type=float, metavar="HZ", help="control rate (default: the policy's metadata)")
    p.add_argument("--seconds", type=float, metavar="S", help="stop cleanly after S seconds, and wait no "
                   "longer than that for the first frame and robot state (default: run until SIGINT/SIGTERM)")
    p.add_argument("--metrics", metavar="PATH", help="write one JSON line per tick (times in monotonic s)")
    p.add_argument("--restore", choices=RESTORE_METHODS, default="none",
                   help="fill depth holes before the policy: inpaint (OpenCV) for a policy trained on clean "
                        "depth; none (default) for a DDG student, which learnt to read them")
    p.add_argument("--seed", type=int, default=0, help="seed of the DDIM start noise (default %(default)s)")
    p.add_argument("--threads", type=int, default=SessionConfig.intra_op_threads,
                   help="onnxruntime intra-op threads (default %(default)s, measured in docs/runtime.md)")
    p.add_argument("--spin", action="store_true", default=SessionConfig.allow_spinning,
                   help="let onnxruntime threads busy-wait (measured slower on 2 cores)")
    p.add_argument("--curve-secret", metavar="FILE",
                   help="this runtime's CurveZMQ .key_secret; required for non-loopback addresses")
    p.add_argument("--curve-server", metavar="FILE", help="the driver's/camera's CurveZMQ public .key")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    announce_priority("runtime")  # before the policy: onnxruntime's threads, started with it, inherit it
    try:
        policy = Policy(args.model, SessionConfig(args.threads, args.spin), seed=args.seed)
        config = loop_config(args, policy.metadata.control_rate_hz)
        keys = CurveKeys.from_files(args.curve_secret, args.curve_server) if args.curve_secret else None
    except (PolicyError, TransportError, ValueError) as exc:
        return _fail(exc, EXIT_USAGE)
    if config.rate_hz != policy.metadata.control_rate_hz:
        print(f"runtime: WARNING running at {config.rate_hz} Hz, the policy was trained at "
              f"{policy.metadata.control_rate_hz} Hz", file=sys.stderr)
    with ExitStack() as stack:
        try:
            camera = stack.enter_context(closing(open_camera(args.camera, policy.metadata.preprocess,
                                                             period_s=config.period)))
            robot = stack.enter_context(closing(RobotLink(args.robot, keys=keys)))
        except CameraError as exc:
            return _fail(exc, EXIT_CAMERA)
        except (TransportError, ValueError) as exc:
            return _fail(exc, EXIT_USAGE)
        metrics = stack.enter_context(open(args.metrics, "w", buffering=1)) if args.metrics else None
        loop = ControlLoop(policy, camera, robot, config, metrics=metrics, stop=stop_on_signals())
        code = loop.run()
        print(f"runtime: done, exit {code}: {loop.counts}", file=sys.stderr)
        return code


def loop_config(args: argparse.Namespace, policy_rate_hz: float) -> LoopConfig:
    """The loop's settings from the command line; a given --rate must be positive (0 is not "default")."""
    if args.rate is not None and not args.rate > 0:
        raise ValueError(f"--rate must be a positive number of Hz, got {args.rate:g}")
    startup = LoopConfig.startup_timeout_s
    if args.seconds is not None and args.seconds > 0:  # a short run should not wait 10 s for a robot
        startup = min(startup, args.seconds)
    return LoopConfig(rate_hz=policy_rate_hz if args.rate is None else args.rate, seconds=args.seconds,
                      restore=args.restore, startup_timeout_s=startup)


def _fail(exc: Exception, code: int) -> int:
    print(f"runtime: error: {exc}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
