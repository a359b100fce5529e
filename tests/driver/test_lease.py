"""The command lease, directly: one sender at a time, sequence numbers increasing, lapse on silence."""

import pytest

from runtime.franka_driver.lease import Lease
from runtime.franka_driver.safety import CommandRejected


def _take(lease: Lease, sender: str, seq: int, now: float) -> bool:
    lease.check(sender, seq, now)
    return lease.renew(sender, seq, now)


def test_first_sender_takes_the_lease_and_a_second_is_refused_while_it_is_live():
    lease = Lease(timeout_s=1.0)
    assert _take(lease, "a", 0, now=10.0)
    with pytest.raises(CommandRejected) as refused:
        lease.check("b", 0, now=10.5)
    assert refused.value.code == "not_controller" and "0.50 s" in refused.value.detail
    assert not _take(lease, "a", 1, now=10.9)  # the holder renews: b stays out a second longer
    with pytest.raises(CommandRejected):
        lease.check("b", 5, now=11.5)


def test_the_lease_lapses_after_the_holders_silence():
    lease = Lease(timeout_s=1.0)
    _take(lease, "a", 0, now=10.0)
    assert lease.live(10.99) and not lease.live(11.0)
    assert _take(lease, "b", 0, now=11.0) and lease.holder == "b"


@pytest.mark.parametrize("seq", [3, 2, 0])
def test_older_and_duplicate_sequence_numbers_are_refused(seq):
    lease = Lease()
    _take(lease, "a", 3, now=0.0)
    with pytest.raises(CommandRejected) as refused:
        lease.check("a", seq, now=0.1)
    assert refused.value.code == "out_of_order" and "3" in refused.value.detail


def test_a_replayed_old_command_stays_old_after_a_lapse():
    lease = Lease(timeout_s=1.0)
    _take(lease, "a", 7, now=0.0)
    with pytest.raises(CommandRejected, match="out_of_order"):
        lease.check("a", 6, now=5.0)
    _take(lease, "a", 8, now=5.0)


def test_release_and_bad_timeout():
    lease = Lease()
    _take(lease, "a", 0, now=0.0)
    lease.release()
    assert not lease.live(0.0) and _take(lease, "b", 0, now=0.0)
    with pytest.raises(ValueError, match="timeout_s"):
        Lease(timeout_s=0)
