import threading
import time

import msgpack
import pytest
import zmq

from runtime.protocol import VERSION, Encoder
from runtime.transport import CurveKeys, Newest, TransportError, bind, connect, is_loopback, send
from tests.runtime.fakes import free_port_pair


@pytest.mark.parametrize("endpoint, local", [
    ("tcp://127.0.0.1:5555", True), ("tcp://127.3.4.5:1", True), ("tcp://localhost:5555", True),
    ("tcp://[::1]:5555", True), ("ipc:///tmp/x", True), ("inproc://x", True),
    ("tcp://0.0.0.0:5555", False), ("tcp://*:5555", False), ("tcp://192.168.1.2:5555", False),
    ("tcp://robot.lab:5555", False), ("tcp://eth0:5555", False),
])
def test_loopback_detection(endpoint, local):
    assert is_loopback(endpoint) is local


def test_bad_scheme_is_named():
    with pytest.raises(TransportError, match="udp://x"):
        is_loopback("udp://x")


@pytest.mark.parametrize("how", [bind, connect])
def test_non_loopback_without_keys_is_refused(how):
    with pytest.raises(TransportError, match="without CurveZMQ keys"):
        how(zmq.Context.instance(), zmq.PUB, f"tcp://0.0.0.0:{free_port_pair()}")


def test_curve_keys_carry_traffic_and_a_wrong_server_key_gets_nothing(tmp_path):
    ctx = zmq.Context.instance()
    server, client = CurveKeys.generate(), CurveKeys.generate()
    port = free_port_pair()
    pub = bind(ctx, zmq.PUB, f"tcp://0.0.0.0:{port}", keys=server)
    good = Newest(connect(ctx, zmq.SUB, f"tcp://127.0.0.1:{port}",
                          keys=CurveKeys(client.public, client.secret, server.public)), "status")
    bad = Newest(connect(ctx, zmq.SUB, f"tcp://127.0.0.1:{port}",
                         keys=CurveKeys(client.public, client.secret, CurveKeys.generate().public)), "status")
    enc, got = Encoder(), None
    end = time.monotonic() + 5
    while got is None and time.monotonic() < end:
        pub.send_multipart(enc.encode("status", code="hello", detail="curve"))
        got = good.poll(0.05)
    assert got is not None and got[0]["code"] == "hello"
    assert bad.poll(0.2) is None
    for s in (pub, good.sock, bad.sock):
        s.close()


def test_curve_keys_from_files(tmp_path):
    import zmq.auth

    zmq.auth.create_certificates(str(tmp_path), "server")
    zmq.auth.create_certificates(str(tmp_path), "client")
    keys = CurveKeys.from_files(tmp_path / "client.key_secret", tmp_path / "server.key")
    assert keys.server_public == zmq.auth.load_certificate(str(tmp_path / "server.key"))[0]
    with pytest.raises(TransportError, match="no secret key"):
        CurveKeys.from_files(tmp_path / "server.key")
    with pytest.raises(TransportError, match="cannot load"):
        CurveKeys.from_files(tmp_path / "missing.key_secret")


def test_newest_keeps_only_the_last_and_survives_garbage():
    ctx = zmq.Context.instance()
    port = free_port_pair()
    pub = bind(ctx, zmq.PUB, f"tcp://127.0.0.1:{port}")
    sub = Newest(connect(ctx, zmq.SUB, f"tcp://127.0.0.1:{port}"), "status")
    enc = Encoder()
    while sub.poll(0.02) is None:  # slow joiner: wait until the subscription is live
        pub.send_multipart(enc.encode("status", code="warmup", detail=""))
    for i in range(3):  # within the high-water mark: a longer burst loses its newest messages in ZeroMQ
        pub.send_multipart(enc.encode("status", code=f"n{i}", detail=""))
    time.sleep(0.1)
    msg, t_receive = sub.poll(0.5)
    assert msg["code"] == "n2" and t_receive <= time.monotonic()
    pub.send_multipart([b"\xc1not msgpack", b""])
    pub.send_multipart([msgpack.packb({"v": 99}), b""])
    pub.send_multipart(enc.encode("state", t_capture=0.0, q=[0.0] * 7, dq=[0.0] * 7, gripper=0.0,
                                  holding=False, fault="", controller=""))
    time.sleep(0.1)
    assert sub.poll(0.1) is None
    assert sub.rejected == 2 and "version" in sub.last_error  # the valid state was skipped, not refused
    pub.close()
    sub.sock.close()


def test_send_never_blocks_without_a_peer():
    sock = connect(zmq.Context.instance(), zmq.PUSH, f"tcp://127.0.0.1:{free_port_pair()}")
    t = time.monotonic()
    results = [send(sock, Encoder().encode("status", code="x", detail="")) for _ in range(10)]
    assert time.monotonic() - t < 0.5 and not any(results)
    sock.close()


def test_poll_waits_at_most_its_timeout():
    ctx = zmq.Context.instance()
    sub = Newest(connect(ctx, zmq.SUB, f"tcp://127.0.0.1:{free_port_pair()}"), "depth")
    t = time.monotonic()
    assert sub.poll(0.1) is None
    assert 0.09 < time.monotonic() - t < 0.3
    sub.sock.close()
    assert threading.active_count() >= 1


def test_robot_state_stays_fresh_when_read_once_per_tick():
    """A 200 Hz state stream read every 100 ms: the newest state the runtime sees must stay young. A shallow
    SUB queue let a backlog of old states build up in the kernel buffer (seconds behind after a few s)."""
    from runtime.loop import RobotLink

    port = free_port_pair()
    pub = bind(zmq.Context.instance(), zmq.PUB, f"tcp://127.0.0.1:{port}")
    pub.sndhwm = 1000
    link = RobotLink(f"tcp://127.0.0.1:{port}")
    stop = threading.Event()

    def publish():
        enc = Encoder()
        while not stop.is_set():
            pub.send_multipart(enc.encode("state", t_capture=time.monotonic(), q=[0.0] * 7, dq=[0.0] * 7,
                                          gripper=0.0, holding=False, fault="", controller=""))
            time.sleep(0.005)

    threading.Thread(target=publish, daemon=True).start()
    try:
        ages = []
        for _ in range(25):
            time.sleep(0.1)
            state = link.poll()
            ages.append(time.monotonic() - state["t_capture"])
    finally:
        stop.set()
        link.close()
        pub.close()
    assert max(ages[5:]) < 0.1, [round(a, 3) for a in ages]


def test_a_deeply_nested_message_on_the_camera_socket_costs_one_message():
    """The same 1 kB nested header that killed the driver killed the runtime through its camera reader."""
    ctx = zmq.Context.instance()
    port = free_port_pair()
    pub = bind(ctx, zmq.PUB, f"tcp://127.0.0.1:{port}")
    sub = Newest(connect(ctx, zmq.SUB, f"tcp://127.0.0.1:{port}"), "status")
    enc = Encoder()
    while sub.poll(0.02) is None:  # slow joiner
        pub.send_multipart(enc.encode("status", code="warmup", detail=""))
    value: list = []
    for _ in range(1000):
        value = [value]
    pub.send_multipart([msgpack.packb({"v": VERSION, "kind": "depth", "seq": value}), b""])
    pub.send_multipart(enc.encode("status", code="after", detail=""))
    msg, _ = sub.poll(1.0)
    assert msg["code"] == "after" and sub.rejected == 1 and "a list of 1 items" in sub.last_error
    pub.close()
    sub.sock.close()
