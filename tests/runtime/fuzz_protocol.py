"""Long fuzz run of runtime.protocol.decode without hypothesis's per-example overhead (run by hand).

    python -m tests.runtime.fuzz_protocol --count 100000 --seed 0

Same five input families as test_protocol_fuzz.py (random frames, random msgpack, one field of a valid message
changed, bytes flipped or cut, a field nested 1..3000 deep), drawn with a seeded numpy Generator. Prints how
many inputs were decoded, refused with ProtocolError, or raised anything else (a bug), with the first few.
"""

from __future__ import annotations

import argparse
import collections

import msgpack
import numpy as np
from tqdm import tqdm

from runtime.protocol import ProtocolError, decode
from tests.runtime.test_protocol_fuzz import _KEYS, VALID


def _value(rng: np.random.Generator, depth: int = 0):
    kind = rng.integers(0, 9 if depth < 2 else 7)
    return [lambda: None, lambda: bool(rng.integers(2)), lambda: int(rng.integers(-(2**63), 2**63 - 1)),
            lambda: float(rng.choice([np.nan, np.inf, -np.inf, rng.normal() * 1e3])),
            lambda: "".join(chr(c) for c in rng.integers(32, 0x2FF, rng.integers(0, 12))),
            lambda: rng.bytes(int(rng.integers(0, 12))), lambda: float(rng.normal()),
            lambda: [_value(rng, depth + 1) for _ in range(rng.integers(0, 9))],
            lambda: {_key(rng): _value(rng, depth + 1) for _ in range(rng.integers(0, 6))}][kind]()


def _key(rng: np.random.Generator) -> str | int:
    return str(rng.integers(0, 99)) if rng.integers(2) else int(rng.integers(0, 99))


def _nested(rng: np.random.Generator) -> list:
    """A valid message with one field's value nested 1..3000 deep in lists or maps (~1 kB at 1,000)."""
    seed = VALID[rng.integers(len(VALID))]
    key = msgpack.packb(_KEYS[rng.integers(len(_KEYS))])
    header = msgpack.unpackb(seed[0]) | {msgpack.unpackb(key): 0}
    raw = msgpack.packb(header, use_bin_type=True)
    at = raw.index(key) + len(key)
    opener = b"\x91" if rng.integers(2) else b"\x81\xa1k"
    return [raw[:at] + opener * int(rng.integers(1, 3001)) + raw[at:], seed[1]]


def _input(rng: np.random.Generator) -> list:
    family = rng.integers(5)
    if family == 4:
        return _nested(rng)
    if family == 0:
        return [rng.bytes(int(rng.integers(0, 64))) for _ in range(rng.integers(0, 4))]
    if family == 1:
        return [msgpack.packb(_value(rng), use_bin_type=True), rng.bytes(int(rng.integers(0, 64)))]
    seed = VALID[rng.integers(len(VALID))]
    if family == 2:
        header = msgpack.unpackb(seed[0])
        key = _KEYS[rng.integers(len(_KEYS))]
        if rng.integers(4) == 0:
            header.pop(key, None)
        else:
            header[key] = _value(rng)
        return [msgpack.packb(header, use_bin_type=True), seed[1] if rng.integers(2) else rng.bytes(40)]
    raw = bytearray(seed[0])
    for _ in range(rng.integers(1, 6)):
        raw[rng.integers(len(raw))] = int(rng.integers(256))
    return [bytes(raw[: rng.integers(0, len(raw) + 1)]), seed[1]]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--count", type=int, default=100_000)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    outcome: collections.Counter[str] = collections.Counter()
    bugs: dict[str, list] = {}
    for _ in tqdm(range(args.count), mininterval=5):
        frames = _input(rng)
        try:
            decode(frames)
            outcome["decoded"] += 1
        except ProtocolError:
            outcome["refused"] += 1
        except Exception as exc:  # what the decoder must never do: anything but ProtocolError
            name = f"{type(exc).__name__}: {exc}"[:120]
            outcome["crashed"] += 1
            bugs.setdefault(name, frames)
    print(dict(outcome))
    for name, frames in list(bugs.items())[:5]:
        print("BUG", name, "header of", len(frames[0]) if frames else 0, "bytes")
    return 1 if outcome["crashed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
