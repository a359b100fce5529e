"""``python -m trainer.eval.sensor_compare``: what a student sees of the same scenes through each sensor
model.

For randomised episodes of the chosen kinds, the scripted expert acts and, at the chosen steps, every sensor
gives its policy-resolution frame through the evaluator's own path (``trainer.sim.rollout.observe``). Writes
a PNG grid (rows: frames, columns: sensors; black = no data) and prints, per sensor, against the clean frame:
hole fraction, share of measurable pixels lost (all, and within the policy's near..far range), share of clean
no-data pixels given a value, and the median absolute error where both have depth.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hil_sim.objects import OBJECTS_HELP, select_kinds  # noqa: E402
from runtime.preprocess import DepthSpec  # noqa: E402
from trainer.sim.env import EnvConfig, GraspEnv  # noqa: E402
from trainer.sim.rollout import expert_scenes, observe  # noqa: E402
from trainer.sim.sensors import SensorError, make_sensor  # noqa: E402

DEFAULT_SENSORS = ("clean", "randnoise", "ddg_nograft:steps=5", "ddg:steps=5", "stereo")


def capture(kinds: tuple[str, ...], specs: list[str], episodes: int, steps: tuple[int, ...], seed: int
            ) -> list[dict[str, np.ndarray]]:
    """One {sensor spec: uint16 frame} per (episode, step)."""
    env, sensors = GraspEnv(EnvConfig(objects=kinds)), {s: make_sensor(s) for s in specs}
    try:
        return [{s: observe(sn, env, info["depth"], "none") for s, sn in sensors.items()}
                for _, _, info in expert_scenes(env, kinds, episodes, steps, seed, sensors.values())]
    finally:
        env.close()


def statistics(frames: list[dict[str, np.ndarray]], spec: DepthSpec | None = None
               ) -> dict[str, dict[str, float]]:
    spec, out = spec or DepthSpec(), {}
    clean = np.stack([f["clean"] for f in frames]).astype(np.float32)
    in_range = (clean >= spec.near_m * 1000) & (clean <= spec.far_m * 1000)
    for name in frames[0]:
        seen = np.stack([f[name] for f in frames]).astype(np.float32)
        both = (clean > 0) & (seen > 0)
        out[name] = {"holes": float(np.mean(seen == 0)),
                     "measurable_lost": float(np.mean(seen[clean > 0] == 0)),
                     "in_range_lost": float(np.mean(seen[in_range] == 0)),
                     "no_data_filled": float(np.mean(seen[clean == 0] > 0)) if (clean == 0).any() else 0.0,
                     "median_abs_err_mm": float(np.median(np.abs(seen[both] - clean[both])))}
    return out


def picture(frames: list[dict[str, np.ndarray]], out: Path, rows: int = 6) -> None:
    """The first ``rows`` frames (the statistics use all of them)."""
    frames, specs = frames[:rows], list(frames[0])
    fig, axes = plt.subplots(len(frames), len(specs), figsize=(2.4 * len(specs), 1.9 * len(frames)),
                             squeeze=False)
    cmap = plt.get_cmap("viridis").copy()
    cmap.set_bad("black")
    for row, frame in enumerate(frames):
        for ax, spec in zip(axes[row], specs, strict=True):
            ax.imshow(np.ma.masked_equal(frame[spec], 0), cmap=cmap, vmin=300, vmax=1500)
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(spec.split(":")[0], fontsize=9)
    fig.suptitle("Policy input through each sensor (mm, 300..1500; black = no data)", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=72)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer.eval.sensor_compare", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sensors", nargs="+", default=list(DEFAULT_SENSORS),
                   help="sensor specs, space-separated (a DDG spec may hold commas: "
                   "ddg:model=DIR,steps=5); the first must be clean, the reference (default: %(default)s)")
    p.add_argument("--objects", default="seen", help=OBJECTS_HELP)
    p.add_argument("--episodes", type=int, default=6)
    p.add_argument("--steps", type=int, nargs="+", default=[0, 60], help="env steps at which to capture")
    p.add_argument("--seed", type=int, default=10_000)
    p.add_argument("--out", type=Path, default=Path("docs/sensor_compare.png"), help="PNG path")
    p.add_argument("--json", type=Path, help="write the statistics here")
    args = p.parse_args(argv)
    specs = args.sensors
    try:
        if specs[0] != "clean":
            raise ValueError(f"the first sensor must be clean (the reference), got {specs[0]!r}")
        if args.episodes < 1 or min(args.steps) < 0:
            raise ValueError("need --episodes >= 1 and --steps >= 0")
        frames = capture(select_kinds(args.objects), specs, args.episodes, tuple(args.steps), args.seed)
    except (SensorError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    stats = statistics(frames)
    picture(frames, args.out)
    if args.json:
        args.json.write_text(json.dumps(stats, indent=2) + "\n")
    for spec, s in stats.items():
        print(f"{spec:<24} holes {s['holes']:6.1%}  measurable lost {s['measurable_lost']:6.1%} "
              f"(in range {s['in_range_lost']:6.1%})  "
              f"no-data filled {s['no_data_filled']:6.1%}  median |err| {s['median_abs_err_mm']:6.1f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
