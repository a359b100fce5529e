import msgpack
import numpy as np
import pytest

from runtime.protocol import (
    MAX_HEADER_BYTES,
    MAX_PAYLOAD_BYTES,
    VERSION,
    Encoder,
    ProtocolError,
    decode,
    robot_endpoints,
)


def _command(enc: Encoder, **over):
    fields = dict(q_target=[0.1] * 7, gripper=1.0, deadline=5.0, t_capture=1.0, session="s" * 32) | over
    return enc.encode("command", **fields)


def test_depth_round_trip_is_raw_and_exact():
    frame = np.arange(6 * 4, dtype=np.uint16).reshape(6, 4)
    frames = Encoder().depth(frame, t_capture=1.5, frame_number=7, depth_scale=0.001)
    assert len(frames[1]) == frame.nbytes  # raw buffer, no per-pixel encoding
    msg = decode(frames)
    np.testing.assert_array_equal(msg.depth(), frame)
    assert (msg["frame"], msg["t_capture"], msg["v"]) == (7, 1.5, VERSION)


def test_sequence_numbers_increase():
    enc = Encoder()
    assert [decode(_command(enc))["seq"] for _ in range(3)] == [0, 1, 2]


def _header(frames):
    return msgpack.unpackb(frames[0])


@pytest.mark.parametrize("mutate, match", [
    (lambda h: h | {"v": VERSION + 1}, "version"),
    (lambda h: h | {"kind": "teleport"}, "unknown message kind"),
    (lambda h: {k: v for k, v in h.items() if k != "deadline"}, "lacks field 'deadline'"),
    (lambda h: h | {"q_target": [0.0] * 6}, "q_target"),
    (lambda h: h | {"q_target": [float("nan")] * 7}, "q_target"),
    (lambda h: h | {"gripper": "close"}, "gripper"),
    (lambda h: h | {"seq": True}, "seq"),
])
def test_bad_headers_are_refused_by_name(mutate, match):
    header = mutate(_header(_command(Encoder())))
    with pytest.raises(ProtocolError, match=match):
        decode([msgpack.packb(header), b""])


def test_truncated_oversized_and_malformed():
    good = Encoder().depth(np.zeros((4, 4), np.uint16), t_capture=0.0, frame_number=0, depth_scale=0.001)
    with pytest.raises(ProtocolError, match="payload"):
        decode([good[0], good[1][:-2]])
    with pytest.raises(ProtocolError, match="exceeds"):
        decode([good[0], b"\0" * (MAX_PAYLOAD_BYTES + 2)])
    with pytest.raises(ProtocolError, match="header of"):
        decode([b"\x80" * (MAX_HEADER_BYTES + 1), b""])
    with pytest.raises(ProtocolError, match="msgpack"):
        decode([good[0][:5], good[1]])
    with pytest.raises(ProtocolError, match="2 frames"):
        decode([good[0]])
    with pytest.raises(ProtocolError, match="map"):
        decode([msgpack.packb([1, 2]), b""])


def test_encoder_refuses_what_a_peer_would_refuse():
    with pytest.raises(ProtocolError):
        _command(Encoder(), q_target=[0.0] * 8)


def test_robot_endpoints():
    assert robot_endpoints("tcp://127.0.0.1:5556") == ("tcp://127.0.0.1:5556", "tcp://127.0.0.1:5557")
    with pytest.raises(ValueError, match="tcp://HOST:PORT"):
        robot_endpoints("localhost")
