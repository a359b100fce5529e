"""``python -m runtime.franka_driver [--bind ADDR]``: serve the real Franka Panda until SIGTERM.

Exit status: 0 stopped by SIGINT/SIGTERM; 1 the robot or a socket failed while serving; 2 bad arguments, keys
or robot connection. The simulated arm is served the same way by ``python -m hil_sim.driver``.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable

from runtime.franka_driver.backend import Backend, BackendError
from runtime.franka_driver.franka_backend import FrankaBackend, FrankaConfig
from runtime.franka_driver.server import DriverConfig, DriverServer, allowed_clients
from runtime.protocol import DEFAULT_ROBOT, robot_endpoints
from runtime.realtime import announce_priority, stop_on_signals
from runtime.transport import CurveKeys, TransportError, check_bind


def parser(prog: str, doc: str) -> argparse.ArgumentParser:
    """The options every driver process takes (this one and ``hil_sim.driver``)."""
    p = argparse.ArgumentParser(prog=prog, description=doc.split("\n\n")[0], epilog=doc.split("\n\n", 1)[1])
    p.add_argument("--bind", default=DEFAULT_ROBOT,
                   help="state endpoint (PUB); commands are PULLed on port + 1; loopback unless keyed")
    p.add_argument("--state-hz", type=float, default=DriverConfig.state_hz,
                   help="control-step and state-publish rate, 100..1000 Hz")
    p.add_argument("--curve-secret", help="CurveZMQ .key_secret file; required for a non-loopback --bind")
    p.add_argument("--curve-clients", metavar="DIR",
                   help="folder of the CurveZMQ public keys (*.key) allowed to connect; required with "
                        "--curve-secret")
    return p


def serve(args: argparse.Namespace, open_backend: Callable[[], Backend], name: str) -> int:
    """Check the options, open the backend and serve it until SIGINT/SIGTERM; the exit status."""
    stop = stop_on_signals()
    try:
        keys = CurveKeys.from_files(args.curve_secret) if args.curve_secret else None
        if keys is not None and args.curve_clients is None:
            raise TransportError("--curve-secret needs --curve-clients DIR, the allow-list of client keys")
        clients = allowed_clients(args.curve_clients) if args.curve_clients else None
        config = DriverConfig(bind=args.bind, state_hz=args.state_hz)
        for endpoint in robot_endpoints(args.bind):
            check_bind(endpoint, keys)  # before the (slow, maybe physical) backend comes up
        announce_priority("franka_driver")  # before the backend: its threads inherit the priority
        backend = open_backend()
    except (TransportError, BackendError, ValueError) as exc:
        print(f"franka_driver: {exc}", file=sys.stderr)
        return 2
    try:
        with DriverServer(backend, config, keys=keys, clients=clients) as server:
            print(f"franka_driver: {name} backend serving state on {args.bind} at {config.state_hz:g} Hz",
                  file=sys.stderr, flush=True)
            server.serve(stop)
    except (TransportError, BackendError) as exc:
        print(f"franka_driver: {exc}", file=sys.stderr)
        return 1
    finally:
        backend.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    p = parser("python -m runtime.franka_driver", __doc__)
    p.add_argument("--backend", choices=("franka", "mujoco"), default="franka",
                   help="franka (default): the real arm; mujoco: hands over to `python -m hil_sim.driver`")
    p.add_argument("--robot-host", default="172.16.0.2", help="the robot's FCI address")
    p.add_argument("--no-realtime", action="store_true", help="do not enforce an RT kernel (bench tests)")
    args = p.parse_args(argv)
    if args.backend == "mujoco":  # the simulated arm lives in hil_sim, which the deploy side never imports
        given = {"bind": args.bind, "state-hz": args.state_hz, "curve-secret": args.curve_secret,
                 "curve-clients": args.curve_clients}
        os.execv(sys.executable, [sys.executable, "-m", "hil_sim.driver",
                                  *(f"--{k}={v}" for k, v in given.items() if v is not None)])
    config = FrankaConfig(host=args.robot_host, realtime=not args.no_realtime)
    return serve(args, lambda: FrankaBackend(config), "franka")


if __name__ == "__main__":
    sys.exit(main())
