"""``python -m runtime.franka_driver --backend franka|mujoco [--bind ADDR]``: serve a robot until SIGTERM."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable

from runtime.franka_driver.backend import Backend, BackendError
from runtime.franka_driver.server import DriverConfig, DriverServer, allowed_clients, check_bind
from runtime.protocol import DEFAULT_ROBOT, robot_endpoints
from runtime.realtime import raise_priority
from runtime.transport import CurveKeys, TransportError


def _franka(args: argparse.Namespace) -> Backend:
    from runtime.franka_driver.franka_backend import FrankaBackend, FrankaConfig
    return FrankaBackend(FrankaConfig(host=args.robot_host, realtime=not args.no_realtime))


def _mujoco(args: argparse.Namespace) -> Backend:
    from runtime.franka_driver.mujoco_backend import standalone
    return standalone()


BACKENDS: dict[str, Callable[[argparse.Namespace], Backend]] = {"franka": _franka, "mujoco": _mujoco}


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m runtime.franka_driver", description=__doc__)
    p.add_argument("--backend", choices=sorted(BACKENDS), required=True,
                   help="franka: the real arm (pylibfranka); mujoco: hil_sim's simulated Panda in real time")
    p.add_argument("--bind", default=DEFAULT_ROBOT,
                   help="state endpoint (PUB); commands are PULLed on port + 1; loopback unless keyed")
    p.add_argument("--state-hz", type=float, default=DriverConfig.state_hz,
                   help="control-step and state-publish rate, 100..1000 Hz")
    p.add_argument("--curve-secret", help="CurveZMQ .key_secret file; required for a non-loopback --bind")
    p.add_argument("--curve-clients", metavar="DIR",
                   help="folder of the CurveZMQ public keys (*.key) allowed to connect; required with "
                        "--curve-secret")
    p.add_argument("--robot-host", default="172.16.0.2", help="franka backend: the robot's FCI address")
    p.add_argument("--no-realtime", action="store_true", help="franka backend: do not enforce an RT kernel")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        keys = CurveKeys.from_files(args.curve_secret) if args.curve_secret else None
        if keys is not None and args.curve_clients is None:
            raise TransportError("--curve-secret needs --curve-clients DIR, the allow-list of client keys")
        clients = allowed_clients(args.curve_clients) if args.curve_clients else None
        config = DriverConfig(bind=args.bind, state_hz=args.state_hz)
        for endpoint in robot_endpoints(args.bind):
            check_bind(endpoint, keys)  # before the (slow, maybe physical) backend comes up
        raised, granted = raise_priority()  # before the backend: its threads inherit the priority
        print(f"franka_driver: {'' if raised else 'WARNING '}{granted}", file=sys.stderr, flush=True)
        backend = BACKENDS[args.backend](args)
    except (TransportError, BackendError, ValueError) as exc:
        print(f"franka_driver: {exc}", file=sys.stderr)
        return 2
    try:
        with DriverServer(backend, config, keys=keys, clients=clients) as server:
            print(f"franka_driver: {args.backend} backend serving state on {args.bind} at "
                  f"{config.state_hz:g} Hz", file=sys.stderr, flush=True)
            server.serve(stop)
    except (TransportError, BackendError) as exc:
        print(f"franka_driver: {exc}", file=sys.stderr)
        return 1
    finally:
        backend.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
