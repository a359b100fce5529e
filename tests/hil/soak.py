"""Soak of the whole HIL loop with memory sampling (issue 44's "Must show"), run by hand:

    python -m tests.hil.soak --seconds 600 --report runs/hil/soak

Runs ``python -m hil_sim``'s benchmark in this process (simulated camera process, physics + driver threads,
the real ``runtime`` process) and samples the resident memory of every process of the tree every 5 s. RSS
growth is measured from the first sample after ``--warmup-s`` (imports, first inference and allocator
arenas settle) to the last. Prints the benchmark's table and one JSON line per process; exit 0 only when the
rate was held (0 late ticks) and every process grew less than 2 %.
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from pathlib import Path

from hil_sim import report
from hil_sim.__main__ import Run, benchmark, resolve_model

GROWTH_LIMIT = 0.02


def _tree(root: int) -> dict[int, str]:
    """pid -> command name of ``root`` and its descendants."""
    parents: dict[int, int] = {}
    names: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            pid, rest = int(entry.name), stat[stat.rindex(")") + 2:].split()
            parents[pid], names[pid] = int(rest[1]), stat[stat.index("(") + 1: stat.rindex(")")]
    tree, grew = {root}, True
    while grew:
        new = {p for p, pp in parents.items() if pp in tree} - tree
        tree |= new
        grew = bool(new)
    return {p: names.get(p, "?") for p in tree}


def _rss_kb(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


class Sampler(threading.Thread):
    def __init__(self, every_s: float = 5.0) -> None:
        super().__init__(daemon=True)
        self.every_s, self.samples = every_s, []  # (t, pid, name, rss_kb); bounded by the run's length
        self.stop = threading.Event()

    def run(self) -> None:
        start = time.monotonic()
        while not self.stop.wait(self.every_s):
            for pid, name in _tree(os.getpid()).items():
                rss = _rss_kb(pid)
                if rss is not None:
                    self.samples.append((time.monotonic() - start, pid, name, rss))


def growth(samples, warmup_s: float) -> list[dict]:
    out = []
    for pid in sorted({s[1] for s in samples}):
        mine = [s for s in samples if s[1] == pid and s[0] >= warmup_s]
        if len(mine) >= 2:
            first, last = mine[0], mine[-1]
            out.append({"pid": pid, "process": first[2], "rss_mb_first": round(first[3] / 1024, 1),
                        "rss_mb_last": round(last[3] / 1024, 1), "seconds": round(last[0] - first[0]),
                        "growth_pct": round(100 * (last[3] - first[3]) / first[3], 2)})
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=600.0)
    p.add_argument("--warmup-s", type=float, default=60.0)
    p.add_argument("--report", type=Path, default=Path("runs/hil/soak"))
    args = p.parse_args(argv)
    sampler = Sampler()
    sampler.start()
    doc = benchmark(Run(args.seconds, 10.0, resolve_model(None), args.report))
    sampler.stop.set()
    rows = growth(sampler.samples, args.warmup_s)
    print(report.table(doc))
    for row in rows:
        print(json.dumps(row))
    held = report.rate_held(doc) and doc["runtime_exit"] == 0
    return 0 if held and all(r["growth_pct"] < 100 * GROWTH_LIMIT for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
