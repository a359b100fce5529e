"""hil_sim's record of executed commands stays bounded (a list of every receipt grew ~12 MB an hour)."""

import numpy as np

from hil_sim.server import CommandLog


def test_the_command_log_keeps_the_newest_receipts_in_fixed_memory():
    log = CommandLog(capacity=8)
    ring = log._ring
    for seq in range(20):
        log.append({"seq": seq, "t_send": 0.0, "deadline": seq + 0.5, "t_receive": seq + 0.1})
    assert len(log) == 20 and log._ring is ring and ring.nbytes == 8 * 3 * 8
    kept = list(log)
    assert [r["seq"] for r in kept] == list(range(12, 20))
    np.testing.assert_allclose([r["t_receive"] - r["seq"] for r in kept], 0.1)
    assert all(r["deadline"] > r["t_receive"] for r in kept)


def test_a_short_run_keeps_everything_in_order():
    log = CommandLog(capacity=8)
    for seq in range(3):
        log.append({"seq": seq, "deadline": 1.0, "t_receive": 0.5})
    assert [r["seq"] for r in log] == [0, 1, 2]


def test_since_gives_the_receipts_from_a_count_on_even_after_the_ring_wrapped():
    log = CommandLog(capacity=4)
    for seq in range(6):
        log.append({"seq": seq, "t_receive": float(seq), "deadline": seq + 0.5})
    assert [r["seq"] for r in log.since(3)] == [3, 4, 5]
    assert [r["seq"] for r in log.since(0)] == [2, 3, 4, 5]  # 0 and 1 were overwritten
    assert log.since(6) == []
