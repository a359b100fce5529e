"""Who may command the arm: one sender at a time, its sequence numbers increasing. Pure, no I/O.

A sender is the ``session`` token its commands carry, prefixed (under CurveZMQ) with the client key the
authenticator verified, so a stolen session token is useless from another key. The first accepted command of
a sender while no lease is live takes the lease; every accepted command of the holder renews it; it lapses
``timeout_s`` after the holder's last accepted command (a runtime that dies frees the arm for the next one).
While it is live, commands of any other sender are refused (``not_controller``), and the holder's commands
must carry a sequence number above the last one accepted (``out_of_order``): a delayed or replayed older
target never moves the arm back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from runtime.franka_driver.safety import CommandRejected


@dataclass
class Lease:
    timeout_s: float = 1.0
    """How long the lease outlives the holder's last accepted command. Longer than any pause of a live
    runtime's 10 Hz command stream (it keeps sending hold commands through its own faults), shorter than a
    runtime restart."""
    holder: str | None = None
    last_seq: int = -1
    renewed_at: float = -math.inf

    def __post_init__(self) -> None:
        if not 0 < self.timeout_s <= 10:
            raise ValueError(f"lease timeout_s must be in (0, 10], got {self.timeout_s}")

    def live(self, now: float) -> bool:
        return self.holder is not None and now - self.renewed_at < self.timeout_s

    def check(self, sender: str, seq: int, now: float) -> None:
        """``CommandRejected`` unless a command ``seq`` of ``sender`` may be executed now."""
        if self.holder == sender:  # even after a lapse: a replayed old command stays old
            if seq <= self.last_seq:
                raise CommandRejected("out_of_order", f"command seq {seq} is not after the last accepted "
                                                      f"{self.last_seq}: dropped")
        elif self.live(now):
            raise CommandRejected("not_controller", f"another session controls the arm (its lease lapses "
                                                    f"{self.timeout_s - (now - self.renewed_at):.2f} s after "
                                                    "its last command): command refused")

    def renew(self, sender: str, seq: int, now: float) -> bool:
        """Record an executed command; True when it changed the holder (a new lease)."""
        new = self.holder != sender or not self.live(now)
        self.holder, self.last_seq, self.renewed_at = sender, seq, now
        return new

    def release(self) -> None:
        self.holder, self.last_seq, self.renewed_at = None, -1, -math.inf
