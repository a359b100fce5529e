"""``python -m trainer <command> ...``: one entry point, one module per command (each has ``main(argv)``)."""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "collect": ("trainer.collect", "record demos from a teacher into a zarr store"),
    "evaluate": ("trainer.evaluate", "closed-loop success rate of a policy in the simulated world"),
    "teacher": ("trainer.teacher.cli", "train the PPO teacher on privileged state"),
    "ddg": ("trainer.ddg.cli", "Diffusion Depth Generator: fit | generate | metrics | paired | bench"),
    "student": ("trainer.student.cli", "diffusion-policy student: fit | init | probe"),
    "table": ("trainer.table", "many evaluate results as one comparison table (success, 95 % CI)"),
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in COMMANDS:
        width = max(map(len, COMMANDS))
        listing = "\n".join(f"  {name:<{width}}  {help_}" for name, (_, help_) in COMMANDS.items())
        print(f"usage: python -m trainer <command> [--help]\n\ncommands:\n{listing}", file=sys.stderr)
        return 0 if argv[:1] in (["-h"], ["--help"]) else 2
    module = importlib.import_module(COMMANDS[argv[0]][0])
    return module.main(argv[1:]) or 0


if __name__ == "__main__":
    sys.exit(main())
