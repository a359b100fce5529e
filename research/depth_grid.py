"""``python research/depth_grid.py``: a PNG grid of what the simulated D455 sees in randomised episodes.

Each row is one episode (random object, dynamics, camera pose and crop window); columns are the full
848x480 frame with the crop window drawn on it, then the policy-resolution frame at three moments of the
scripted expert's grasp. No-data pixels (0) are black.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hil_sim.objects import GROUPS  # noqa: E402
from trainer.policies import Observation, make_policy  # noqa: E402
from trainer.sim.env import EnvConfig, GraspEnv  # noqa: E402


def _frames(env: GraspEnv, seed: int, kind: str, moments: tuple[float, ...]) -> tuple[np.ndarray, list, dict]:
    obs, info = env.reset(seed=seed, options={"kind": kind})
    full = env.world.render_depth()
    expert = make_policy("scripted")
    expert.reset(info)
    frames = [info["depth"]]
    while True:
        obs, _, terminated, truncated, info = env.step(expert.act(Observation(obs, None, info["state"])))
        frames.append(info["depth"])
        if terminated or truncated:
            break
    picks = [frames[min(len(frames) - 1, int(m * (len(frames) - 1)))] for m in moments]
    return full, picks, {"success": info["success"], "steps": len(frames) - 1}


def render_grid(out: Path, episodes: int = 4, seed: int = 100) -> Path:
    env = GraspEnv(EnvConfig(objects=GROUPS["all"]))
    moments = (0.0, 0.55, 1.0)
    kinds = GROUPS["all"]
    fig, axes = plt.subplots(episodes, 1 + len(moments), figsize=(4 * (1 + len(moments)), 2.6 * episodes),
                             gridspec_kw={"width_ratios": [1.6] + [1] * len(moments)})
    cmap = plt.get_cmap("viridis").copy()
    cmap.set_bad("black")
    for row in range(episodes):
        kind = kinds[(row * 5) % len(kinds)]
        full, picks, result = _frames(env, seed + row, kind, moments)
        top, left = env.world.episode.crop_window
        spec = env.spec
        for col, (ax, img) in enumerate(zip(axes[row], [full, *picks], strict=True)):
            ax.imshow(np.ma.masked_equal(img, 0), cmap=cmap, vmin=300, vmax=2000)
            ax.set_xticks([])
            ax.set_yticks([])
            if col == 0:
                ax.add_patch(plt.Rectangle((left, top), spec.crop_width, spec.crop_height, fill=False,
                                           edgecolor="white", linewidth=1.2))
                ax.set_ylabel(f"{kind} (seed {seed + row})\n{'grasped' if result['success'] else 'missed'}")
        if row == 0:
            titles = ["848x480 stream, crop window", "policy input t=0", "mid grasp", "lifted"]
            for ax, title in zip(axes[0], titles, strict=True):
                ax.set_title(title)
    fig.suptitle("Simulated D455 depth (mm, 300..2000 shown; black = no data)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    env.close()
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python research/depth_grid.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("docs/depth_grid.png"), help="PNG path")
    p.add_argument("--episodes", type=int, default=4, help="rows (randomised episodes)")
    p.add_argument("--seed", type=int, default=100, help="seed of the first episode")
    args = p.parse_args(argv)
    print(render_grid(args.out, args.episodes, args.seed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
