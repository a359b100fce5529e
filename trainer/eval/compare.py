"""``python -m trainer compare A.json B.json``: two ``trainer evaluate`` results on the same episodes, episode
by episode.

Two policies run on the same seeds and kinds met the same scenes, so what counts is the episodes where they
differ: B won (A failed, B grasped) and B lost. Under "no difference" either is equally likely, so the exact
two-sided McNemar test is a binomial test of the won count among the differing ones. It separates policies
whose 95 % intervals overlap: with 180 episodes each, 17 won against 6 lost is p = 0.035.
Prints one line per kind and the total; ``--json`` also writes them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from scipy import stats

from trainer.sim.rollout import schedule


class CompareError(ValueError):
    """A file that is not a ``trainer evaluate`` result, or two results not run on the same episodes."""


def episodes(path: Path) -> tuple[dict[int, str], set[int], str]:
    """(seed -> kind, failed seeds, policy) of one result; kinds cycle through ``objects`` from ``seed``."""
    try:
        result = json.loads(path.read_text())
        kinds, first, n = result["objects"], int(result["seed"]), int(result["episodes"])
        failed = {int(s) for s in result["failed_seeds"]}
        policy = str(result["policy"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise CompareError(f"{path}: not a trainer evaluate result with failed_seeds ({exc})") from None
    return {job.seed: job.kind for job in schedule(kinds, first, n)}, failed, policy


def mcnemar_p(won: int, lost: int) -> float:
    """Exact two-sided McNemar p of ``won`` against ``lost`` discordant episodes (1 when there are none)."""
    return float(stats.binomtest(won, won + lost, 0.5).pvalue) if won + lost else 1.0


def compare(a: Path, b: Path) -> dict:
    kinds_a, failed_a, policy_a = episodes(a)
    kinds_b, failed_b, policy_b = episodes(b)
    if kinds_a != kinds_b:
        raise CompareError(f"{a} and {b} did not run the same episodes (seeds and kinds differ): run both "
                           "with the same --objects, --episodes and --seed")
    rows: dict[str, dict] = {}
    for kind in dict.fromkeys(kinds_a.values()):  # in the results' order
        seeds = {s for s, k in kinds_a.items() if k == kind}
        rows[kind] = _row(seeds, failed_a, failed_b)
    return {"a": policy_a, "b": policy_b, "sources": [str(a), str(b)], "kinds": rows,
            "all": _row(set(kinds_a), failed_a, failed_b)}


def _row(seeds: set[int], failed_a: set[int], failed_b: set[int]) -> dict:
    won, lost = len(seeds & failed_a - failed_b), len(seeds & failed_b - failed_a)
    return {"episodes": len(seeds), "a_success": len(seeds - failed_a), "b_success": len(seeds - failed_b),
            "b_won": won, "b_lost": lost, "p": round(mcnemar_p(won, lost), 4)}


def table(result: dict) -> str:
    width = max(map(len, [*result["kinds"], "ALL"]))
    lines = [f"A = {result['a']}", f"B = {result['b']}",
             f"{'':<{width}} {'A':>5} {'B':>5} {'B won':>6} {'B lost':>7} {'p':>7}"]
    for name, row in [*result["kinds"].items(), ("ALL", result["all"])]:
        lines.append(f"{name:<{width}} {row['a_success']:>5} {row['b_success']:>5} {row['b_won']:>6} "
                     f"{row['b_lost']:>7} {row['p']:>7.3g}   (of {row['episodes']})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer compare", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", type=Path, help="the baseline's trainer evaluate --json result")
    p.add_argument("b", type=Path, help="the challenger's, run on the same episodes")
    p.add_argument("--json", type=Path, help="write the comparison here")
    args = p.parse_args(argv)
    try:
        result = compare(args.a, args.b)
    except CompareError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(table(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
