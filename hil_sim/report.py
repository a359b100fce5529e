"""The HIL benchmark's report: joins the runtime's per-tick metrics with the driver's command receipts.

Definitions (all from CLOCK_MONOTONIC, comparable across the processes of one host):

* ``latency_ms``            frame received by the runtime -> its command received by the driver
* ``frame_age_ms``          camera capture -> inference start (end of preprocessing), inference ticks only
* ``capture_to_command_ms`` camera capture -> command received by the driver
* ``stages_ms``             receive->preprocessed, preprocessed->inferred, inferred->sent, sent->driver
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

RATE_TOLERANCE = 0.01


class ReportError(ValueError):
    """The runtime's metrics cannot be turned into a report (missing, empty, malformed)."""


@dataclass(frozen=True)
class Usage:
    """Resources of the runtime process over the run."""

    cpu_percent: float
    rss_mb: float


def load_ticks(path: Path) -> list[dict[str, Any]]:
    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise ReportError(f"cannot read runtime metrics {path}: {exc}") from None
    try:
        ticks = [json.loads(line) for line in lines if line.strip()]
    except json.JSONDecodeError as exc:
        raise ReportError(f"runtime metrics {path} are not JSON lines: {exc}") from None
    if not ticks:
        raise ReportError(f"runtime metrics {path} hold no ticks")
    return ticks


def _summary(values_s: Iterable[float], keys: tuple[str, ...] = ("p50", "p99", "max")) -> dict[str, float]:
    ms = np.asarray(list(values_s), dtype=float) * 1e3
    if ms.size == 0:
        return {k: float("nan") for k in keys}
    stats = {"p50": np.percentile(ms, 50), "p99": np.percentile(ms, 99), "max": ms.max()}
    return {k: round(float(stats[k]), 3) for k in keys}


def _diffs(rows: list[dict[str, Any]], start: str, end: str) -> list[float]:
    return [r[end] - r[start] for r in rows if r.get(start) is not None and r.get(end) is not None]


def join(ticks: list[dict[str, Any]], commands: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each tick with ``t_driver``: when the driver received its command (None if it never did)."""
    received = {c["seq"]: c["t_receive"] for c in commands}
    return [dict(t, t_driver=received.get(t.get("cmd_seq"))) for t in ticks]


def build(ticks: list[dict[str, Any]], commands: list[dict[str, Any]], *, rate_hz: float,
          usage: Usage, late_share: float = 0.0) -> dict[str, Any]:
    """The report.json document; up to ``late_share`` of its ticks may miss their deadline in a held rate."""
    rows = join(ticks, commands)
    inferred = [r for r in rows if r.get("t_inference") is not None]  # ticks that started an inference
    # Achieved rate end to end: commands the driver received over the run's span (a lost command lowers it;
    # a late one is counted by late_ticks).
    arrivals = sum(r["t_driver"] is not None for r in rows)
    span = ticks[-1]["deadline"] - ticks[0]["deadline"]
    achieved = (arrivals - 1) / span if span > 0 and arrivals > 1 else 0.0
    return {
        "rate_hz_target": rate_hz,
        "rate_hz_achieved": round(achieved, 4),
        "ticks": len(ticks),
        "late_ticks": sum(bool(t.get("late")) for t in ticks),
        "late_ticks_allowed": int(late_share * len(ticks)),
        "latency_ms": _summary(_diffs(rows, "t_receive", "t_driver")),
        "frame_age_ms": _summary(_diffs(inferred, "t_capture", "t_preprocess")),
        "capture_to_command_ms": _summary(_diffs(rows, "t_capture", "t_driver")),
        "stages_ms": {
            "preprocess": _summary(_diffs(rows, "t_receive", "t_preprocess"), ("p50", "p99")),
            "inference": _summary(_diffs(rows, "t_preprocess", "t_inference"), ("p50", "p99")),
            "send": _summary(_diffs(rows, "t_inference", "t_send"), ("p50", "p99")),
            "transport": _summary(_diffs(rows, "t_send", "t_driver"), ("p50", "p99")),
        },
        "commands_received": sum(r["t_driver"] is not None for r in rows),
        "cpu_percent": round(usage.cpu_percent, 1),
        "rss_mb": round(usage.rss_mb, 1),
    }


def rate_held(report: dict[str, Any]) -> bool:
    """No more ticks missed their deadline than the run allowed (none by default) and the achieved rate is
    within 1 % of the target."""
    target = report["rate_hz_target"]
    return (report["late_ticks"] <= report.get("late_ticks_allowed", 0) and report["ticks"] > 1
            and abs(report["rate_hz_achieved"] - target) <= RATE_TOLERANCE * target)


def table(report: dict[str, Any]) -> str:
    """A plain-text summary for the terminal."""
    allowed = report.get("late_ticks_allowed", 0)
    lines = [f"rate      target {report['rate_hz_target']:g} Hz, "
             f"achieved {report['rate_hz_achieved']:.3f} Hz, "
             f"{report['ticks']} ticks, {report['late_ticks']} late"
             f"{f' (up to {allowed} allowed)' if allowed else ''} -> "
             f"{'HELD' if rate_held(report) else 'NOT HELD'}",
             f"{'metric (ms)':<24}{'p50':>9}{'p99':>9}{'max':>9}"]
    for key in ("latency_ms", "frame_age_ms", "capture_to_command_ms"):
        s = report[key]
        lines.append(f"{key:<24}{s['p50']:>9.2f}{s['p99']:>9.2f}{s['max']:>9.2f}")
    for stage, s in report["stages_ms"].items():
        lines.append(f"  stage {stage:<16}{s['p50']:>9.2f}{s['p99']:>9.2f}")
    lines.append(f"runtime cpu {report['cpu_percent']:.1f} %, peak rss {report['rss_mb']:.1f} MB")
    if report.get("host_steal_percent") is not None:
        lines.append(f"host steal {report['host_steal_percent']:.1f} % of the cores' time "
                     "(taken by the hypervisor, beyond any priority here)")
    return "\n".join(lines)


LATENCY_GOAL_MS = 25.0
"""The runtime's latency goal at 10 Hz (docs/runtime.md): frame received -> command at the driver, p99."""


def frame_age_caption(rate_hz: float, camera_fps: float | None) -> str | None:
    """Why capture -> command has two clusters when the camera is slower than the loop; None otherwise."""
    if camera_fps is None or camera_fps >= rate_hz:
        return None
    return (f"The camera ({camera_fps:.3g} fps) is slower than the loop ({rate_hz:g} Hz): ticks between two "
            "frames act on the last frame again, one loop period older, so capture -> command falls in two "
            "clusters a period apart.")


def histogram(ticks: list[dict[str, Any]], commands: list[dict[str, Any]], path: Path, *, title: str,
              rate_hz: float, camera_fps: float | None = None) -> None:
    """PNG: the latency distributions (left) and each tick's latency over the run (right), both with the
    goal and the tick period as lines; late ticks marked on the right."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = join(ticks, commands)
    caption = frame_age_caption(rate_hz, camera_fps)
    fig, (hist, over_time) = plt.subplots(1, 2, figsize=(11, 4.4 if caption else 4))
    for start, label in (("t_receive", "frame received -> command at driver"),
                         ("t_capture", "capture -> command at driver")):
        values = np.asarray(_diffs(rows, start, "t_driver")) * 1e3
        if values.size:
            hist.hist(values, bins=60, alpha=0.6, label=f"{label} (p99 {np.percentile(values, 99):.1f} ms)")
    hist.set_xlabel("ms")
    hist.set_ylabel("ticks")
    _ticks_over_time(over_time, rows)
    lines = ((LATENCY_GOAL_MS, {"color": "green", "ls": "--", "label": f"goal {LATENCY_GOAL_MS:g} ms"}),
             (1e3 / rate_hz, {"color": "black", "ls": ":", "label": f"tick period {1e3 / rate_hz:g} ms"}))
    for ms, style in lines:
        hist.axvline(ms, **style)
        over_time.axhline(ms, **style)
    hist.legend(fontsize=7)
    over_time.legend(fontsize=7)
    reached = any(r["t_driver"] is not None for r in rows)
    fig.suptitle(title if reached else f"{title}: no command reached the driver")
    if caption:
        fig.text(0.5, 0.01, caption, ha="center", fontsize=8, wrap=True)
    fig.tight_layout(rect=(0, 0.06 if caption else 0, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _ticks_over_time(ax: Any, rows: list[dict[str, Any]]) -> None:
    """Frame received -> command at the driver per tick, seconds into the run; late ticks as red crosses at
    their latency (or on the axis when their command never arrived)."""
    t0 = rows[0]["deadline"] if rows else 0.0
    done = [r for r in rows if r.get("t_receive") is not None and r["t_driver"] is not None]
    ax.plot([r["deadline"] - t0 for r in done], [1e3 * (r["t_driver"] - r["t_receive"]) for r in done], ".",
            ms=3, label="frame received -> command at driver")
    late = [r for r in rows if r.get("late")]
    ax.plot([r["deadline"] - t0 for r in late],
            [1e3 * (r["t_driver"] - r["t_receive"]) if r in done else 0.0 for r in late], "x", color="red",
            ms=7, label=f"late ticks ({len(late)})")
    ax.set_xlabel("s into the run")
    ax.set_ylabel("ms")
