"""``python -m hil_sim.driver`` (the simulated arm behind runtime.franka_driver's server) as a real process:
serves, refuses, stops holding. The old ``python -m runtime.franka_driver --backend mujoco`` hands over to
it."""

import signal
import subprocess
import sys
import time

import pytest
import zmq

from runtime.protocol import Encoder, robot_endpoints
from tests.hil.rig import REPO, StateLog, subprocess_env
from tests.runtime.fakes import free_port_pair

pytestmark = pytest.mark.hil
SIM_DRIVER = [sys.executable, "-m", "hil_sim.driver"]
OLD_SIM_DRIVER = [sys.executable, "-m", "runtime.franka_driver", "--backend", "mujoco"]


def test_mujoco_driver_process_serves_state_takes_commands_and_stops_on_sigterm(tmp_path):
    addr = f"tcp://127.0.0.1:{free_port_pair()}"
    cmd = [*SIM_DRIVER, "--bind", addr]
    proc = subprocess.Popen(cmd, cwd=REPO, env=subprocess_env(), stderr=open(tmp_path / "driver.log", "w"))
    log = StateLog(addr)
    ctx = zmq.Context()
    push = ctx.socket(zmq.PUSH)
    push.connect(robot_endpoints(addr)[1])
    try:
        first = log.wait(lambda s: True, timeout=60, what="a state from the driver process")
        time.sleep(1.0)
        rate = sum(s.t > first.t for s in log.states) / (log.states[-1].t - first.t)
        assert rate >= 100, f"state published at {rate:.0f} Hz"
        assert all(s.holding for s in log.states)
        push.send_multipart([b"\xc1", b""])
        now = time.monotonic()
        push.send_multipart(Encoder().encode("command", t_capture=now, q_target=list(log.states[-1].q),
                                             gripper=-1.0, deadline=now + 0.15, session="cli-test" * 4))
        log.wait(lambda s: not s.holding, timeout=5, what="the command taken")
        log.wait(lambda s: s.holding and s.fault == "command_timeout", timeout=1, what="hold after expiry")
        assert "bad_message" in log.codes()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        push.close(0)
        ctx.term()
        log.close()


@pytest.mark.parametrize("driver", [SIM_DRIVER, OLD_SIM_DRIVER], ids=["hil_sim.driver", "--backend mujoco"])
def test_non_loopback_bind_without_keys_exits_2_with_one_line(tmp_path, driver):
    cmd = [*driver, "--bind", "tcp://0.0.0.0:5999"]
    done = subprocess.run(cmd, cwd=REPO, env=subprocess_env(), capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "CurveZMQ" in done.stderr and len(done.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("driver", [SIM_DRIVER, OLD_SIM_DRIVER], ids=["hil_sim.driver", "--backend mujoco"])
def test_curve_keys_without_a_client_allow_list_exit_2_with_one_line(tmp_path, driver):
    import zmq.auth

    zmq.auth.create_certificates(str(tmp_path), "driver")
    cmd = [*driver, "--bind", "tcp://0.0.0.0:5999", "--curve-secret", str(tmp_path / "driver.key_secret")]
    done = subprocess.run(cmd, cwd=REPO, env=subprocess_env(), capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "--curve-clients" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
