"""``python -m trainer table RESULT.json ...``: many ``trainer evaluate`` results as one comparison table.

Rows are policies (the policy file's stem, with as many of its folders as tell the table's policies apart:
``row_a/c1/student`` and ``row_b/c1/student``; "+ inpaint" when the runtime restored holes), columns are
sensor x object group; a cell is the success rate with its 95 % Wilson interval and episode count, and where
the result has one, the median horizontal hand-object distance at the first gripper close with its interval.
Prints markdown; ``--out`` also writes the table as JSON with every cell's source file, and ``--base`` builds
on such a JSON (new results replace its cells, the rest stay).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path, PurePosixPath

from hil_sim.objects import GROUPS
from trainer.eval.stats import wilson_interval

CELL_KEYS = ("success_rate", "successes", "episodes", "ci95", "closes_cm", "closes_cm_ci95", "source")


class TableError(ValueError):
    """A result file that is not a ``trainer evaluate`` JSON, or two results for one cell."""


def load(path: Path) -> dict:
    try:
        result = json.loads(path.read_text())
        successes = round(result["success_rate"] * result["episodes"])
        policy = result["policy"].partition(":")[2] or result["policy"]
        restore = result.get("restore", "none")
        closes = result.get("first_close", {})
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise TableError(f"{path}: not a trainer evaluate result ({exc})") from None
    objects = next((name for name, kinds in GROUPS.items() if list(kinds) == result["objects"]),
                   ",".join(result["objects"]))
    n = result["episodes"]
    return {"policy": policy, "restore": "" if restore == "none" else f" + {restore}",
            "column": f"{result['sensor']} {objects}", "success_rate": result["success_rate"],
            "successes": successes, "episodes": n,
            "ci95": [round(b, 4) for b in wilson_interval(successes, n)],
            "closes_cm": closes.get("horizontal_cm_median"),
            "closes_cm_ci95": closes.get("horizontal_cm_median_ci95"),
            "source": str(path)}


def build(paths: list[Path], base: dict | None = None) -> dict:
    """The table of ``paths``' results on top of ``base`` (an earlier table's JSON): its cells are kept
    unless a result measures the same cell again, which replaces it."""
    rows = (base or {}).get("rows", {})
    table: dict[str, dict[str, dict]] = {row: dict(cells) for row, cells in rows.items()}
    measured: set[tuple[str, str]] = set()
    cells = [load(p) for p in paths]
    names = row_names({c["policy"] for c in cells})
    for c in cells:
        c["row"] = names[c["policy"]] + c["restore"]
        if (c["row"], c["column"]) in measured:
            raise TableError(f"two results for {c['row']} / {c['column']}: "
                             f"{table[c['row']][c['column']]['source']} and {c['source']}")
        measured.add((c["row"], c["column"]))
        table.setdefault(c["row"], {})[c["column"]] = {k: c[k] for k in CELL_KEYS}
    columns = sorted({column for cells in table.values() for column in cells},
                     key=lambda c: (c.split()[0] != "clean", c))
    return {"columns": columns, "rows": table}


def row_names(policies: set[str]) -> dict[str, str]:
    """Each policy file's name without its suffix, with the fewest of its last folders that tell it apart
    from every other policy's (the whole path where nothing less does)."""
    parts = {p: PurePosixPath(p).with_suffix("").parts for p in policies}

    def name(p: str) -> str:
        for k in range(1, len(parts[p]) + 1):
            if all(parts[q][-k:] != parts[p][-k:] for q in policies - {p}):
                return "/".join(parts[p][-k:])
        return p

    return {p: name(p) for p in policies}


def load_base(path: Path) -> dict:
    try:
        base = json.loads(path.read_text())
        if not isinstance(base.get("rows"), dict):
            raise ValueError("no rows")
    except (OSError, ValueError, AttributeError) as exc:
        raise TableError(f"--base {path}: not a table written by --out ({exc})") from None
    return base


def markdown(doc: dict) -> str:
    columns = doc["columns"]
    lines = ["| policy | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for row, cells in doc["rows"].items():
        lines.append(f"| {row} | " + " | ".join(_cell(cells.get(c)) for c in columns) + " |")
    return "\n".join(lines)


def _cell(cell: dict | None) -> str:
    if cell is None:
        return "-"
    lo, hi = cell["ci95"]
    text = f"{cell['success_rate']:.1%} [{lo:.0%}, {hi:.0%}] n={cell['episodes']}"
    if cell.get("closes_cm") is not None:
        text += f", closes {cell['closes_cm']:.1f} cm"
        if cell.get("closes_cm_ci95"):
            text += " [{:.1f}, {:.1f}]".format(*cell["closes_cm_ci95"])
    return text


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer table", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", nargs="+", type=Path, help="JSON files written by trainer evaluate --json")
    p.add_argument("--out", type=Path, help="also write the table as JSON here")
    p.add_argument("--base", type=Path, help="an earlier --out table: its cells stay unless a result "
                   "measures the same cell again (result files of earlier sessions need not be at hand)")
    args = p.parse_args(argv)
    try:
        doc = build(args.results, args.base and load_base(args.base))
    except TableError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(markdown(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
