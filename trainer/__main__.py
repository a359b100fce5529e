"""``python -m trainer <command> ...``: one entry point, one module per command (each has ``main(argv)``)."""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "collect": ("trainer.collect", "record demos from a teacher into a zarr store"),
    "evaluate": ("trainer.eval.success", "closed-loop success rate of a policy in the simulated world"),
    "teacher": ("trainer.teacher.cli", "train the PPO teacher on privileged state"),
    "ddg": ("trainer.ddg.cli", "Diffusion Depth Generator: fit | generate | metrics | paired | bench"),
    "student": ("trainer.student.cli", "diffusion-policy student: fit | init | probe"),
    "table": ("trainer.eval.table", "many evaluate results as one comparison table (success, 95 % CI)"),
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] in (["-h"], ["--help"]):
        print(usage())  # asked-for help is output, not an error: stdout, exit 0
        return 0
    if not argv or argv[0] not in COMMANDS:
        problem = f"unknown command {argv[0]!r}" if argv else "no command given"
        print(f"{usage()}\npython -m trainer: error: {problem}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[argv[0]][0])
    return module.main(argv[1:]) or 0


def usage() -> str:
    width = max(map(len, COMMANDS))
    listing = "\n".join(f"  {name:<{width}}  {help_}" for name, (_, help_) in COMMANDS.items())
    return f"usage: python -m trainer <command> [--help]\n\ncommands:\n{listing}"

if __name__ == "__main__":
    sys.exit(main())
