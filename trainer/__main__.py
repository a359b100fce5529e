"""``python -m trainer <command> ...``: one entry point, one module per command (each has ``main(argv)``)."""

from __future__ import annotations

import signal
import sys

from trainer.menu import Menu

MENU = Menu("python -m trainer", {
    "collect": ("record demos from a teacher into a zarr store", "trainer.collect:main"),
    "evaluate": ("closed-loop success rate of a policy in the simulated world", "trainer.eval.success:main"),
    "teacher": ("train the PPO teacher on privileged state", "trainer.teacher.cli:main"),
    "ddg": ("Diffusion Depth Generator: fit | generate | metrics | paired | bench", "trainer.ddg.cli:main"),
    "student": ("diffusion-policy student: fit | recipe | refit | readout | compose | init | probe",
                "trainer.student.cli:main"),
    "compare": ("two evaluate results on the same episodes, episode by episode (exact McNemar)",
                "trainer.eval.compare:main"),
    "table": ("many evaluate results as one comparison table (success, 95 % CI)", "trainer.eval.table:main"),
})
main = MENU.main


def _stop(signum: int, frame) -> None:
    """SIGTERM (``kill``, a scheduler's stop) ends a command as Ctrl-C does, not at once: Python's exit then
    terminates its worker pool, which a bare SIGTERM leaves running, orphaned, on the next job's cores."""
    raise KeyboardInterrupt


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _stop)
    sys.exit(main())
