"""Is the stereo readout's error on a new scene set by the scene or by the sensor's draw (issue 45)?

On new scenes the ceiling's readout reads the object's place 1.2-1.3 cm off while the hand is 12-30 cm over
it, one constant per episode (``docs/table2.md``). If that constant is a function of the scene (the object's
shape, pose and the hand's place, through the stereo matcher's deterministic errors), more scenes can teach
it; if it follows the sensor's random draws (each episode's IR material parameters and noise), no frame of
that episode holds it. The expert drives ``--episodes`` episodes under stereo; at ``--frames`` of each
episode's steps with the hand 12-30 cm over the object, the same world state is rendered again under
``--draws`` other sensor draws: with the episode's own object material (only the frame noise drawn anew) and
with everything drawn anew (material kind and parameters too), and once as clean depth. The readout's
horizontal error is split into the part shared by every draw of a frame (the scene's) and the part that
changes with the draw.

    PYTHONPATH=. python research/sensor_draw_readout.py CKPT [--episodes 30] [--draws 4] [--out J]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hil_sim.objects import select_kinds
from hil_sim.stereo.sensor import episode_rng
from runtime.preprocess import crop_resize, normalise
from trainer.dataset import DEPTH_SCALE
from trainer.policies import Observation, make_policy
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.labels import OFFSET, frame_labels
from trainer.sim.rollout import schedule, start_episode
from trainer.sim.sensors import make_sensor
from trainer.student import checkpoint
from trainer.student.model import hand_pose

HIGH_CM = (12.0, 30.0)
"""Heights of the grasp site over the object whose frames are rendered again (where the aim is set)."""
CONDITIONS = ("clean", "stereo", "noise", "all")
"""The world rendered again as clean depth; the episode's own stereo frame; its world rendered again under new
noise alone (the episode's material kept) and under a whole new draw (material kind, parameters and noise)."""


def rendered(env: GraspEnv, sensor, snapshots: list, condition: str, draw: int, seed: int) -> np.ndarray:
    """The uint16 policy-resolution frames of ``snapshots`` (a stack, oldest first) under ``condition``."""
    if condition == "all":
        sensor.reset(env.world, seed * 1000 + draw + 1)
    elif condition == "noise":
        # the episode's materials kept, only the noise drawn anew
        sensor._rng = episode_rng(seed * 1000 + draw + 1)
    frames = []
    for snap in snapshots:
        env.world.restore(snap)
        if condition == "clean":
            frames.append(env.frame())
        else:
            frames.append(crop_resize(sensor.stream(env.world), env.spec, env.world.episode.crop_window))
    return np.stack(frames)


def read(net, frames: np.ndarray, state: np.ndarray, spec) -> np.ndarray:
    """The readout's offset (m) of one frame stack."""
    depth = torch.from_numpy(normalise(frames, DEPTH_SCALE, spec))[None]
    state = torch.from_numpy(state.astype(np.float32))[None]
    with torch.no_grad():
        _, facts, _ = net.perception(depth, net.hand_norm.normalise(hand_pose(state)))
    return net.label_norm.unnormalise(facts).float().numpy()[0, OFFSET]


def episode_rows(env, sensor, net, job, draws: int, per_episode: int, spec) -> list[dict]:
    """The expert drives ``job``; at up to ``per_episode`` of its high steps, the readout's error under every
    condition and draw."""
    expert = make_policy("scripted")
    info = start_episode(env, expert, job, (sensor,))
    horizon = net.config.obs_horizon
    history, picked = [], []
    obs = env.observation()
    while True:  # first pass: the expert's episode, remembering its states
        labels = frame_labels(env)
        history.append((env.world.snapshot(), info["state"].copy(), labels,
                        crop_resize(sensor.stream(env.world), env.spec, env.world.episode.crop_window)))
        above = -labels[OFFSET][2] * 100
        if HIGH_CM[0] <= above < HIGH_CM[1] and len(history) >= horizon:
            picked.append(len(history) - 1)
        obs, _, terminated, truncated, info = env.step(expert.act(Observation(obs, None, info["state"])))
        if terminated or truncated or above < HIGH_CM[0] - 2:
            break
    keep = [picked[int(i)] for i in np.linspace(0, len(picked) - 1, min(per_episode, len(picked)))]
    rows = []
    for t in keep:
        stack = history[t - horizon + 1:t + 1]
        snaps, state, labels = [s[0] for s in stack], stack[-1][1], stack[-1][2]
        errors = {"stereo": [read(net, np.stack([s[3] for s in stack]), state, spec) - labels[OFFSET]]}
        for condition in ("clean", "noise", "all"):
            n = 1 if condition == "clean" else draws
            errors[condition] = [read(net, rendered(env, sensor, snaps, condition, k, job.seed), state, spec)
                                 - labels[OFFSET] for k in range(n)]
        sensor.reset(env.world, job.seed)  # the episode's own draws back for the next frame's "noise"
        rows.append({"seed": job.seed, "kind": job.kind, "above_cm": float(-labels[OFFSET][2] * 100),
                     **{c: (np.array(e)[:, :2] * 100).tolist() for c, e in errors.items()}})
    return rows


def summary(rows: list[dict]) -> dict:
    """Per condition, the horizontal error's median (cm); per redrawn condition, the share of its variance
    that is the frame's own (shared by every draw) and the median size of that shared part."""
    out = {}
    for c in CONDITIONS:
        e = np.concatenate([np.array(r[c]) for r in rows])
        out[c] = {"error_cm_median": round(float(np.median(np.linalg.norm(e, axis=1))), 3)}
    for c in ("noise", "all"):
        e = np.stack([np.array(r[c]) for r in rows])  # [frames, draws, 2]
        shared = e.mean(axis=1, keepdims=True)
        total = ((e - e.reshape(-1, 2).mean(0)) ** 2).sum()
        within = ((e - shared) ** 2).sum()
        out[c].update(scene_share=round(float(1 - within / total), 3),
                      shared_error_cm_median=round(float(np.median(np.linalg.norm(shared[:, 0], axis=1))), 3),
                      draw_spread_cm_median=round(float(np.median(np.linalg.norm(e - shared, axis=2))), 3))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--draws", type=int, default=4)
    p.add_argument("--frames", type=int, default=3, help="frames rendered again per episode")
    p.add_argument("--objects", default="seen,squares,shapes")
    p.add_argument("--seed", type=int, default=59000)
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    torch.set_num_threads(1)
    ckpt = checkpoint.load(args.checkpoint)
    spec, net = ckpt.info.depth_spec, ckpt.policy()
    env, sensor = GraspEnv(EnvConfig(objects=select_kinds(args.objects), depth=spec)), make_sensor("stereo")
    rows = []
    for job in tqdm(schedule(env.config.objects, args.seed, args.episodes), desc="episodes"):
        rows += episode_rows(env, sensor, net, job, args.draws, args.frames, spec)
    result = {"checkpoint": str(args.checkpoint), "episodes": args.episodes, "draws": args.draws,
              "frames": len(rows), "summary": summary(rows), "rows": rows}
    print(json.dumps(result["summary"], indent=1))
    if args.out:
        args.out.write_text(json.dumps(result))


if __name__ == "__main__":
    main()
