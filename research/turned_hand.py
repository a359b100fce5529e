"""Does the readout read a turned hand worse, and do grasps that need a large wrist turn fail? (issue 42)

The fingers close along the hand's closing axis, which at the home wrist lies across the camera's line of
sight; an elongated object needs a turn of up to 90 degrees (the fingers are symmetric: the nearer way
round), a round one none. Two measurements:

``readout STORE --student CKPT``: the student's horizontal offset error near the object (hand within 5 cm of
it horizontally and 6 cm above it, ``readout.NEAR_M``) by how far the hand is turned from the home wrist,
per kind. A store whose episodes start from a turned wrist, the expert driving (it keeps a round object's
wrist as it starts), turns the hand independently of the object: the effect of the turn alone. ``trainer
student readout --wrist-noise 1.57`` made one (412c895, reverted in fb515bf).

``success RESULT.json ... --kinds lemon bread``: the episodes of ``trainer evaluate`` results (or of
``research/composed_policy.py``'s, seeds 10000.. one kind) by the turn their object needs from the home
wrist, as ``hil_sim.world.World.reset`` draws it from each episode's seed.

``close POLICY --kinds lemon --min-turn 75 --episodes 40``: the policy run (clean depth) on the first seeds
from 10000 whose object needs at least that turn, and where its fingers were at its first close
(``research/m0_failures.py``'s ``FirstClose``): the object's offset across the pads (they forgive ~0.7 cm
there) and along the closing axis, by turn. A head that drifts sideways while its wrist turns shows it here.

    PYTHONPATH=. python research/turned_hand.py readout STORE.zarr --student CKPT
    PYTHONPATH=. python research/turned_hand.py success A.json [B.json ...] --kinds lemon bread
    PYTHONPATH=. python research/turned_hand.py close oracle:CKPT --kinds lemon --min-turn 75 --episodes 40
"""

from __future__ import annotations

import argparse
import json
from itertools import islice
from pathlib import Path

import numpy as np
import torch

from hil_sim.world import World
from research.m0_failures import FirstClose
from trainer.dataset import DemoStore
from trainer.policies import depth_spec, make_policy
from trainer.sim.env import EnvConfig, GraspEnv
from trainer.sim.labels import OFFSET
from trainer.sim.rollout import Job, run_episode, schedule
from trainer.student.model import hand_pose
from trainer.student.readout import offset_errors, perceive_store

BINS = ((0, 15), (15, 30), (30, 45), (45, 60), (60, 75), (75, 90.001))
"""Turns, degrees."""
HOME_CLOSING_YAW = np.pi / 2
"""The home wrist's closing axis lies along the base frame's y (``World.finger_positions`` at ``HOME_Q``)."""


def turn_from_home(yaw: np.ndarray) -> np.ndarray:
    """|turn| (degrees, 0..90) from the home closing axis to a closing axis at ``yaw`` (modulo pi)."""
    return np.degrees(np.abs((yaw - HOME_CLOSING_YAW + np.pi / 2) % np.pi - np.pi / 2))


def needed_turn(world: World, kind: str, seed: int) -> float:
    """The turn an episode's object needs: its narrow axis lies at its yaw + 90 degrees."""
    return float(turn_from_home(np.array(world.reset(kind, seed).object_yaw + np.pi / 2)))


def readout_by_turn(store_path: Path, student: Path) -> dict:
    """Median horizontal offset error (cm) near the object by the hand's turn, over all kinds and per kind."""
    facts, _, steps = perceive_store(student, store_path)
    labels = steps.labels_np[:, :facts.shape[1]]
    closing = hand_pose(torch.from_numpy(steps.state_np))[:, 6:8].numpy()
    turn = turn_from_home(np.arctan2(closing[:, 1], closing[:, 0]))
    error, near = offset_errors(facts, labels)
    near &= -labels[:, OFFSET][:, 2] < 0.06
    horizontal = np.linalg.norm(error[:, :2], axis=1)
    store = DemoStore.open(store_path)
    kinds = np.repeat(store.kinds, store.episode_lengths)
    rows = {}
    for kind in ["all", *sorted(set(kinds))]:
        mine = near & ((kinds == kind) if kind != "all" else True)
        rows[kind] = {f"{lo:.0f}-{hi:.0f}": _cell(horizontal[mine & (turn >= lo) & (turn < hi)])
                      for lo, hi in BINS}
    return rows


def _cell(errors: np.ndarray) -> str:
    return f"{np.median(errors):.2f} cm ({len(errors)})" if len(errors) >= 20 else f"- ({len(errors)})"


def success_by_turn(results: list[Path], kinds: list[str]) -> dict:
    """Grasped / episodes of ``kinds`` by the turn their object needs, over the result files."""
    episodes = []
    for path in results:
        r = json.loads(path.read_text())
        if "failed_seeds" in r:  # trainer evaluate
            failed = {int(s) for s in r["failed_seeds"]}
            jobs = schedule(tuple(r["objects"]), int(r["seed"]), int(r["episodes"]))
            episodes += [(job.kind, job.seed, job.seed not in failed) for job in jobs if job.kind in kinds]
        else:  # composed_policy.py run on one kind, seeds 10000..
            (kind,) = r["by_kind"]
            episodes += [(kind, 10_000 + i, bool(ok)) for i, ok in enumerate(r["grasped"]) if kind in kinds]
    world = World(tuple(kinds))
    turns = np.array([needed_turn(world, kind, seed) for kind, seed, _ in episodes])
    grasped = np.array([ok for _, _, ok in episodes])
    out = {}
    for lo, hi in BINS:
        mine = (turns >= lo) & (turns < hi)
        out[f"{lo:.0f}-{hi:.0f}"] = f"{grasped[mine].sum()} / {mine.sum()}"
    return out


def close_by_turn(spec: str, kinds: list[str], min_turn: float, episodes: int) -> dict:
    """Per kind and turn bin: grasped / episodes, and the median offsets (cm) across the pads and along the
    closing axis at the first close, of the grasps and of the misses apart."""
    env = GraspEnv(EnvConfig(objects=tuple(kinds), randomise=True, depth=depth_spec(spec)))
    policy, out = FirstClose(make_policy(spec), env), {}
    for kind in kinds:
        world, rows = World((kind,)), []
        turns = ((seed, needed_turn(world, kind, seed)) for seed in range(10_000, 10_000 + 100 * episodes))
        for seed, turn in islice(((s, t) for s, t in turns if t >= min_turn), episodes):
            success = run_episode(env, policy, Job(seed, kind)).success
            rows.append((turn, success, *policy.close[2][:2]))
        table = np.array(rows, float)
        out[kind] = {f"{lo:.0f}-{hi:.0f}": _close_cell(table[(table[:, 0] >= lo) & (table[:, 0] < hi)])
                     for lo, hi in BINS if lo + 15 > min_turn}
    return out


def _close_cell(rows: np.ndarray) -> str:
    def medians(chosen: np.ndarray) -> str:
        return f"{np.nanmedian(chosen[:, 3]):.2f} / {np.nanmedian(chosen[:, 2]):.2f}" if len(chosen) else "-"

    grasped = rows[:, 1] == 1
    return (f"{int(grasped.sum())} / {len(rows)}; across / along, cm: grasped {medians(rows[grasped])}, "
            f"missed {medians(rows[~grasped])}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    r = sub.add_parser("readout")
    r.add_argument("store", type=Path)
    r.add_argument("--student", type=Path, required=True)
    s = sub.add_parser("success")
    s.add_argument("results", type=Path, nargs="+")
    s.add_argument("--kinds", nargs="+", required=True)
    c = sub.add_parser("close")
    c.add_argument("policy", help="oracle:CKPT | reactive | student:ONNX")
    c.add_argument("--kinds", nargs="+", required=True)
    c.add_argument("--min-turn", type=float, default=75.0, help="degrees")
    c.add_argument("--episodes", type=int, default=40, help="per kind")
    args = p.parse_args()
    if args.what == "readout":
        out = readout_by_turn(args.store, args.student)
    elif args.what == "success":
        out = success_by_turn(args.results, args.kinds)
    else:
        out = close_by_turn(args.policy, args.kinds, args.min_turn, args.episodes)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
