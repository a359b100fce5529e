"""The driver server over real ZeroMQ sockets on loopback, with a kinematic fake robot behind it."""

import subprocess
import sys
import threading
import time

import msgpack
import numpy as np
import pytest
import zmq

from runtime.franka_driver.kinematics import DQ_MAX, READY_Q
from runtime.franka_driver.server import DriverConfig, DriverServer
from runtime.protocol import Encoder, decode, robot_endpoints
from runtime.transport import CurveKeys, TransportError, connect, send
from tests.driver.fake_backend import KinematicArm
from tests.runtime.fakes import free_port_pair

TIMEOUT = 5.0
SESSION = "a" * 32


def command(enc, q, *, gripper=-1.0, valid_for=0.1, session=SESSION):
    now = time.monotonic()
    return enc.encode("command", t_capture=now, q_target=list(map(float, q)), gripper=gripper,
                      deadline=now + valid_for, session=session)


class Harness:
    """A driver serving in a thread, plus a client (SUB on state, PUSH on commands)."""

    def __init__(self, arm: KinematicArm, **config) -> None:
        self.arm = arm
        self.addr = f"tcp://127.0.0.1:{free_port_pair()}"
        self.received: list[dict] = []
        self.server = DriverServer(arm, DriverConfig(bind=self.addr, **config),
                                   on_command=self.received.append)
        self.stop = threading.Event()
        self.ctx = zmq.Context()
        state_ep, command_ep = robot_endpoints(self.addr)
        self.sub = self.ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.sub.connect(state_ep)
        self.push = self.ctx.socket(zmq.PUSH)
        self.push.connect(command_ep)
        self.enc = Encoder()

    def __enter__(self):
        self.server.__enter__()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()
        self.error: BaseException | None = None
        self.next_kind("state")
        return self

    def _serve(self):
        try:
            self.server.serve(self.stop)
        except BaseException as exc:  # handed to the test thread
            self.error = exc

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(TIMEOUT)
        self.server.__exit__(None, None, None)
        self.sub.close(0)
        self.push.close(0)
        self.ctx.term()

    def send_command(self, q, *, gripper=-1.0, valid_for=0.1, session=SESSION, enc=None, push=None):
        (push or self.push).send_multipart(command(enc or self.enc, q, gripper=gripper, valid_for=valid_for,
                                                   session=session))

    def next_kind(self, kind: str, *, timeout=TIMEOUT, where=lambda m: True):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.sub.poll(int(max(1, (end - time.monotonic()) * 1000))):
                msg = decode(self.sub.recv_multipart())
                if msg.kind == kind and where(msg):
                    return msg
        raise TimeoutError(f"no {kind} message within {timeout} s")


def test_publishes_state_at_at_least_100_hz():
    with Harness(KinematicArm(), state_hz=200.0) as h:
        first = h.next_kind("state")
        n, t0 = 0, time.monotonic()
        while time.monotonic() - t0 < 1.0:
            h.next_kind("state")
            n += 1
        last = h.next_kind("state")
    assert n >= 100, f"only {n} states in 1 s (contract: >= 100 Hz)"
    assert last["seq"] > first["seq"] and np.allclose(last["q"], READY_Q)


def test_command_moves_the_arm_within_velocity_limits_and_records_receive_time():
    with Harness(KinematicArm()) as h:
        goal = READY_Q + 0.05
        end = time.monotonic() + TIMEOUT
        while time.monotonic() < end and not np.allclose(h.arm.q, goal, atol=1e-6):
            h.send_command(goal)
            time.sleep(0.02)
        assert np.allclose(h.arm.q, goal, atol=1e-6)
        state = h.next_kind("state", where=lambda m: not m["holding"])
        assert state["fault"] == ""
    assert h.received and all(r["t_receive"] >= r["t_send"] for r in h.received)
    steps = np.diff(np.array([q for _, q in h.arm.history]), axis=0)
    assert np.all(np.abs(steps) <= DQ_MAX * 0.5 / 200.0 * 3 + 1e-9)  # a late step may cover <= 3 periods


def test_missing_commands_hold_within_250_ms_and_announce_it():
    with Harness(KinematicArm()) as h:
        h.send_command(READY_Q + 0.2, valid_for=10.0)  # a deadline far away: the age cap must still apply
        h.next_kind("state", where=lambda m: not m["holding"])
        t_last = time.monotonic()
        status = h.next_kind("status", where=lambda m: m["code"] == "command_timeout")
        held = h.next_kind("state", where=lambda m: m["holding"])
        t_held = time.monotonic()
        q1 = np.array(h.next_kind("state")["q"])
        time.sleep(0.1)
        q2 = np.array(h.next_kind("state")["q"])
    assert t_held - t_last < 0.25 and held["fault"] == "command_timeout"
    assert "holding" in status["detail"] and np.array_equal(q1, q2)


@pytest.mark.parametrize("frames, code", [
    ([b"\xc1\xc1", b""], "bad_message"),
    ([msgpack.packb({"v": 99, "kind": "command"}), b""], "bad_message"),
    ([msgpack.packb({"v": 1, "kind": "command", "seq": 0, "t_send": 0.0}), b""], "bad_message"),
    ([b"x" * 5000, b""], "bad_message"),
    (Encoder().encode("status", code="hello", detail=""), "wrong_kind"),
    (Encoder().encode("command", t_capture=0.0, q_target=[0.0] * 7, gripper=0.0, deadline=1.0,
                      session=SESSION), "stale_command"),
])
def test_bad_messages_are_answered_with_status_and_the_driver_keeps_serving(frames, code):
    with Harness(KinematicArm()) as h:
        h.push.send_multipart(frames)
        status = h.next_kind("status", where=lambda m: m["code"] == code)
        assert status["detail"]
        h.next_kind("state")  # still alive
        assert h.error is None and np.allclose(h.arm.q, READY_Q)


def test_oversized_frame_is_dropped_by_the_transport_and_the_driver_keeps_serving():
    with Harness(KinematicArm()) as h:
        h.push.send_multipart([b"x" * 2_000_000, b""])
        time.sleep(0.1)
        h.next_kind("state")
        assert h.error is None and np.allclose(h.arm.q, READY_Q)


def test_backend_failure_announces_and_leaves_the_arm_holding():
    arm = KinematicArm()
    with Harness(arm) as h:
        arm.fail_reads = True
        status = h.next_kind("status", where=lambda m: m["code"] == "backend_error")
        h.thread.join(TIMEOUT)
        assert "communication lost" in status["detail"] and h.error is not None
    assert arm.held >= 1


def test_non_loopback_bind_without_keys_is_refused():
    with pytest.raises(TransportError, match="CurveZMQ"):
        with DriverServer(KinematicArm(), DriverConfig(bind="tcp://0.0.0.0:5999")):
            pass


def nested(depth: int = 1000) -> list:
    value: list = []
    for _ in range(depth):
        value = [value]
    return value


def test_a_deeply_nested_message_is_refused_and_the_driver_keeps_serving():
    """A list nested 1,000 deep in a header field (1,015 bytes) killed the driver with RecursionError."""
    frames = [msgpack.packb({"v": 2, "kind": "command", "seq": nested()}), b""]
    assert len(frames[0]) < 1100
    with Harness(KinematicArm()) as h:
        h.push.send_multipart(frames)
        status = h.next_kind("status", where=lambda m: m["code"] == "bad_message")
        assert "a list of 1 items" in status["detail"]
        h.send_command(READY_Q + 0.01, valid_for=1.0)
        h.next_kind("state", where=lambda m: not m["holding"])
        assert h.error is None and h.server.rejected["bad_message"] == 1


def test_any_exception_while_handling_costs_one_message(monkeypatch):
    arm = KinematicArm()
    with Harness(arm) as h:
        real, calls = h.server.safety.accept, []

        def flaky(**kw):
            calls.append(kw)
            if len(calls) == 1:
                raise RuntimeError("a bug in the safety layer")
            return real(**kw)

        monkeypatch.setattr(h.server.safety, "accept", flaky)
        h.send_command(READY_Q + 0.01, valid_for=1.0)
        status = h.next_kind("status", where=lambda m: m["code"] == "handler_error")
        assert "RuntimeError" in status["detail"]
        h.send_command(READY_Q + 0.01, valid_for=1.0)
        h.next_kind("state", where=lambda m: not m["holding"])
        assert h.error is None and h.server.rejected == {"handler_error": 1}


def _second_sender(h: Harness):
    push = h.ctx.socket(zmq.PUSH)
    push.connect(robot_endpoints(h.addr)[1])
    return push, Encoder()


def _until_controller(h: Harness, send, where) -> dict:
    """Send (a loaded machine may deliver one command past its deadline) until a state's controller fits."""
    end = time.monotonic() + TIMEOUT
    while time.monotonic() < end:
        send()
        try:
            return h.next_kind("state", timeout=0.05, where=lambda m: where(m["controller"]))
        except TimeoutError:
            continue
    raise TimeoutError("the controller never changed")


def test_a_second_controller_is_refused_while_the_first_holds_the_lease():
    """While the runtime commanded 'stay still', a second local process moved joint 0 by 0.5 rad."""
    arm = KinematicArm()
    with Harness(arm, lease_s=0.5) as h:
        push, enc = _second_sender(h)
        try:
            owner = _until_controller(h, lambda: h.send_command(READY_Q, valid_for=0.5), where=bool)
            for _ in range(20):  # the stranger keeps trying while the owner keeps commanding 'stay'
                h.send_command(READY_Q, valid_for=0.1)
                h.send_command(READY_Q + [0.5, 0, 0, 0, 0, 0, 0], session="b" * 32, enc=enc, push=push)
                time.sleep(0.01)
            status = h.next_kind("status", where=lambda m: m["code"] == "not_controller")
            assert np.abs(arm.q - READY_Q).max() < 1e-9 and h.server.rejected["not_controller"] >= 1
            assert "another session" in status["detail"]
            time.sleep(0.6)  # the owner fell silent: its lease lapses and the next sender may take the arm
            _until_controller(h, lambda: h.send_command(READY_Q + [0.01, 0, 0, 0, 0, 0, 0], session="b" * 32,
                                                        enc=enc, push=push),
                              where=lambda c: c not in ("", owner["controller"]))
        finally:
            push.close(0)


def test_older_and_duplicate_commands_are_dropped():
    """An older command received after a newer one moved the arm back to the older target."""
    arm = KinematicArm()
    with Harness(arm) as h:
        enc = Encoder()
        newer_first = [command(enc, READY_Q + 0.02, valid_for=2.0) for _ in range(2)]
        h.push.send_multipart(newer_first[1])  # seq 1 arrives before seq 0 ...
        h.push.send_multipart(newer_first[0])
        h.push.send_multipart(newer_first[1])  # ... and again
        status = h.next_kind("status", where=lambda m: m["code"] == "out_of_order")
        assert "not after the last accepted 1" in status["detail"]
        end = time.monotonic() + TIMEOUT
        while time.monotonic() < end and h.server.rejected["out_of_order"] < 2:
            time.sleep(0.01)
        assert h.server.rejected["out_of_order"] == 2 and [r["seq"] for r in h.received] == [1]


def _flood(addr: str, seconds: float) -> subprocess.Popen:
    code = ("import sys, time, zmq\n"
            "push = zmq.Context().socket(zmq.PUSH); push.connect(sys.argv[1])\n"
            "end = time.monotonic() + float(sys.argv[2])\n"
            "while time.monotonic() < end: push.send_multipart([b'\\xc1garbage', b''])\n")
    return subprocess.Popen([sys.executable, "-c", code, robot_endpoints(addr)[1], str(seconds)])


def _states_per_second(h: Harness, seconds: float) -> tuple[float, int]:
    """State rate the driver published over ``seconds`` and the statuses a subscriber saw meanwhile."""
    steps, statuses, end = h.server.steps, 0, time.monotonic() + seconds
    while time.monotonic() < end:
        if h.sub.poll(10):
            statuses += decode(h.sub.recv_multipart()).kind == "status"
    return (h.server.steps - steps) / seconds, statuses


def test_a_garbage_flood_is_reported_rate_limited_and_leaves_the_state_rate():
    """A 10 s garbage flood once put 85,329 statuses on the state socket and cost 12 % of the state rate."""
    with Harness(KinematicArm()) as h:
        normal, _ = _states_per_second(h, 1.5)
        flood = _flood(h.addr, 4.0)
        try:
            end = time.monotonic() + TIMEOUT
            while h.server.rejected["bad_message"] < 100 and time.monotonic() < end:
                time.sleep(0.01)
            flooded, statuses = _states_per_second(h, 1.5)
        finally:
            flood.kill()
            flood.wait()
    assert h.server.rejected["bad_message"] > 1000, h.server.rejected
    assert statuses <= 1.5 / 0.1 + 2, f"{statuses} statuses in 1.5 s of flood"
    assert flooded >= 0.9 * normal, f"state rate {flooded:.0f} Hz under the flood, {normal:.0f} Hz before"


def test_curve_driver_needs_an_allow_list_and_refuses_unlisted_client_keys(tmp_path):
    import zmq.auth

    server, stranger = CurveKeys.generate(), CurveKeys.generate()
    zmq.auth.create_certificates(str(tmp_path), "runtime")
    allowed = CurveKeys.from_files(tmp_path / "runtime.key_secret")
    (tmp_path / "clients").mkdir()
    (tmp_path / "runtime.key").rename(tmp_path / "clients" / "runtime.key")
    with pytest.raises(TransportError, match="allow-list"):
        DriverServer(KinematicArm(), DriverConfig(), keys=server)
    with pytest.raises(TransportError, match="holds no public key"):
        DriverServer(KinematicArm(), DriverConfig(), keys=server, clients=tmp_path / "nothing")
    arm, addr, stop = KinematicArm(), f"tcp://127.0.0.1:{free_port_pair()}", threading.Event()
    ctx = zmq.Context()
    driver = DriverServer(arm, DriverConfig(bind=addr), keys=server, clients=tmp_path / "clients",
                          context=ctx)
    with driver:
        thread = threading.Thread(target=driver.serve, args=(stop,), daemon=True)
        thread.start()
        try:
            moved = {}
            for name, keys, goal in (("stranger", stranger, READY_Q + 0.03),
                                     ("allowed", allowed, READY_Q + 0.01)):
                push = connect(ctx, zmq.PUSH, robot_endpoints(addr)[1],
                               keys=CurveKeys(keys.public, keys.secret, server.public))
                end = time.monotonic() + 2.0
                while time.monotonic() < end and not np.allclose(arm.q, goal):
                    send(push, command(Encoder(), goal, session=name * 4))
                    time.sleep(0.02)
                moved[name] = bool(np.allclose(arm.q, goal))
                push.close(0)
        finally:
            stop.set()
            thread.join(TIMEOUT)
    ctx.term()
    assert moved == {"stranger": False, "allowed": True}
