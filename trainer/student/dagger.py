"""DAgger rounds for the student: a learner drives, the reactive expert labels every state it reaches.

Each step records the frame (depth, when the learner reads it), the joint state, the frame's perception labels
(``trainer.sim.labels``) and the expert's action chunk from that state (``GraspEnv.lookahead``: the expert run
ahead in the physics, which is then rolled back), then executes the learner's action, or, with probability
``beta``, the expert's, so that early learners still reach the grasp and lift states and get them labelled.
Round 0 has no learner: the expert drives, and its chunk labels are its own next actions, which equal its
lookahead (it is memoryless and the physics deterministic). A learner's episode ends as the env's do or once
the hand has stalled. Every episode is kept, failures included: their labels say how to recover.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from trainer.dataset import DemoStore, EpisodeRecord
from trainer.policies import NEEDS_DEPTH, Observation, make_policy, parse
from trainer.sim.env import HAND_POSITION, EnvConfig, GraspEnv
from trainer.sim.labels import OFFSET, frame_labels
from trainer.sim.rollout import Job, in_workers, observe, schedule, start_episode
from trainer.sim.sensors import Sensor, make_sensor
from trainer.teacher.scripted import ReactiveExpert


@dataclass(frozen=True)
class RoundSpec:
    learner: str = ""
    """Policy spec of the learner (``student:ONNX``, ``oracle:CKPT``); "" = the expert drives (round 0)."""
    beta: float = 0.0
    """Probability that a learner step executes the expert's action instead."""
    horizon: int = 16
    """Length of the expert's action chunk recorded as each step's label (the student's action horizon); 0
    records the frames' perception labels alone, which is all a readout refit reads (``trainer student refit
    --perception-only``): the expert's lookahead is ~3/4 of a learner episode's time."""
    stall_steps: int = 10
    """A learner episode ends once the hand moved less than ``stall_m`` over this many steps."""
    stall_m: float = 0.002
    end_height_m: float = 0.0
    """An episode ends once the grasp site is first this low over the object's centre (0: never), before that
    frame is stored: a store of the approach alone, whose frames set where the hand aims. Under the stereo
    sensor the readout reads a hand low beside the object as on target, so the aim is fixed 12 cm up and more,
    and ~27 % of a learner episode's frames lie up there (``docs/table2.md``)."""
    glimpse: int = 0
    """0 keeps every frame. N > 0 (with ``end_height_m``): a glimpse of where the aim is set; the episode ends
    once the grasp site is first below a height drawn per episode between ``end_height_m`` and
    ``GLIMPSE_TOP_M``, and only its last N frames are kept, the only ones rendered (clean and through the
    sensor): ~5x the scenes per hour of an approach, for drivers that read no depth (the expert,
    ``reactive:B``, ``oracle:CKPT@B``). What they teach a readout under stereo: ``docs/table2.md``."""
    sensor: str = "clean"
    """What the learner sees (``trainer.sim.sensors``: ``ddg``, ``stereo`` ...); other than ``clean``, the
    store keeps its frames as ``data/depth_sensor`` beside the clean ones, and a fit reads them with
    ``--depth-source sensor``."""

    def __post_init__(self) -> None:
        if self.glimpse < 0:
            raise ValueError(f"glimpse must be >= 0 frames, got {self.glimpse}")
        if self.glimpse and not (self.end_height_m > 0 and self.horizon == 0):
            raise ValueError("a glimpse needs an end height (--end-height-cm) and frames labelled alone "
                             "(--no-chunks)")
        if self.glimpse and self.learner and NEEDS_DEPTH[parse(self.learner)[0]]:
            raise ValueError(f"a glimpse renders only the frames it keeps: its driver must read no depth, "
                             f"not {self.learner}")


GLIMPSE_TOP_M = 0.30
"""The highest a glimpse ends, grasp site over the object: the top of the heights where the aim is set."""


def chunks_ahead(actions: np.ndarray, horizon: int) -> np.ndarray:
    """[T, A] -> [T, horizon, A]: each step's next ``horizon`` actions, the last one repeated past the end."""
    index = np.minimum(np.arange(len(actions))[:, None] + np.arange(horizon), len(actions) - 1)
    return actions[index]


def labelled_episode(env: GraspEnv, expert: ReactiveExpert, learner, job: Job, spec: RoundSpec,
                     sensor: Sensor | None = None) -> tuple[EpisodeRecord, bool]:
    """One episode of ``job`` driven by ``learner`` (None: the expert), every step labelled; returns its
    record and whether it succeeded. With a ``sensor``, the learner reads its frames and the record keeps them
    (``depth_sensor``) beside the clean ones."""
    info = start_episode(env, learner or expert, job, (sensor,))
    expert.reset(info)
    rng = np.random.default_rng([job.seed, 0xDA66])
    steps: dict[str, list] = {"depth": [], "seen": [], "state": [], "action": [], "labels": [], "chunk": []}
    hands, snapshots = [], []
    stop_m = (np.random.default_rng([job.seed, 0x611]).uniform(spec.end_height_m, GLIMPSE_TOP_M)
              if spec.glimpse else spec.end_height_m)
    while True:
        obs, labels = env.observation(), frame_labels(env)
        if hands and -labels[OFFSET][2] < stop_m:
            break
        steps["labels"].append(labels)
        if spec.glimpse:  # rendered once the glimpse's last frames are known
            snapshots = [*snapshots, env.world.snapshot()][-spec.glimpse:]
            seen = None
        else:
            seen = info.get("depth") if sensor is None else observe(sensor, env, info.get("depth"), "none")
        steps["seen"].append(seen)
        if learner is None:
            action = np.asarray(expert.act(obs), np.float32)
        else:
            chunk = env.lookahead(expert.act, spec.horizon) if spec.horizon else None
            if chunk is not None:
                steps["chunk"].append(chunk)
            action = np.asarray(learner.act(Observation(obs, seen, info["state"])), np.float32)
            if rng.random() < spec.beta:  # drawn at every step alike, so both label modes drive the same
                action = chunk[0] if chunk is not None else np.asarray(expert.act(obs), np.float32)
        for key, value in (("depth", info.get("depth")), ("state", info["state"]), ("action", action)):
            steps[key].append(value)
        hands.append(obs[HAND_POSITION])
        _, _, terminated, truncated, info = env.step(action)
        stalled = (learner is not None and len(hands) >= spec.stall_steps
                   and np.linalg.norm(hands[-1] - hands[-spec.stall_steps]) < spec.stall_m)
        if terminated or truncated or stalled:
            break
    if spec.glimpse:
        steps = glimpsed(env, sensor, steps, snapshots)
    actions = np.stack(steps["action"])
    chunks = (np.stack(steps["chunk"]) if steps["chunk"]
              else chunks_ahead(actions, spec.horizon) if spec.horizon else None)
    depth = (np.stack(steps["depth"]) if steps["depth"][0] is not None
             else np.zeros((len(actions), env.spec.out_height, env.spec.out_width), np.uint16))
    world = env.world
    record = EpisodeRecord(depth, np.stack(steps["state"]), actions, job.kind, job.seed,
                           world.episode.crop_window, world.intr.K, world.camera_extrinsics(),
                           world.episode.to_dict(), labels=np.stack(steps["labels"]), chunk=chunks,
                           depth_sensor=None if sensor is None else np.stack(steps["seen"]))
    return record, bool(info["success"])


def glimpsed(env: GraspEnv, sensor: Sensor | None, steps: dict[str, list], snapshots: list
             ) -> dict[str, list]:
    """The last of an episode's ``steps``, one per physics snapshot kept, their frames rendered now."""
    kept = {key: values[-len(snapshots):] for key, values in steps.items()}
    kept["depth"], kept["seen"] = [], []
    for snapshot in snapshots:
        env.world.restore(snapshot)
        depth = env.frame()
        kept["depth"].append(depth)
        kept["seen"].append(depth if sensor is None else observe(sensor, env, depth, "none"))
    return kept


_WORKER: dict = {}


def _init(config: EnvConfig, spec: RoundSpec) -> None:
    _WORKER.update(env=GraspEnv(config), expert=ReactiveExpert(), spec=spec,
                   learner=make_policy(spec.learner) if spec.learner else None,
                   sensor=None if spec.sensor == "clean" else make_sensor(spec.sensor))


def _work(job: Job) -> tuple[EpisodeRecord, bool]:
    w = _WORKER
    return labelled_episode(w["env"], w["expert"], w["learner"], job, w["spec"], w["sensor"])


def collect_round(path: Path, config: EnvConfig, spec: RoundSpec, *, episodes: int, seed: int,
                  workers: int = 1) -> dict:
    """Episodes ``seed``.. (kinds in turn) into the store at ``path``, resumed where it stopped; returns the
    store's tally."""
    make_sensor(spec.sensor)  # an unknown sensor fails here in one line, not in every worker
    if spec.glimpse:
        config = replace(config, render_depth=False)  # the kept frames are rendered at the end
    store = DemoStore.create(path, spec=config.depth, action_scale=config.action_scale,
                             control_rate_hz=config.control_rate_hz, labels=True, chunk_horizon=spec.horizon,
                             sensor=None if spec.sensor == "clean" else spec.sensor,
                             attrs={"teacher": "reactive", "learner": spec.learner, "beta": spec.beta,
                                    "end_height_m": spec.end_height_m, "glimpse": spec.glimpse,
                                    "seed": seed, "objects": list(config.objects)})
    kinds = config.objects
    jobs = schedule(kinds, seed, episodes, int(store.attrs["attempted"]))
    bar = tqdm(total=episodes, initial=episodes - len(jobs), desc=f"round {path.stem}", unit="ep")
    for record, success in in_workers(_init, (config, spec), _work, jobs, workers, _WORKER):
        store.append(record)
        store.count(success=success)
        bar.update(1)
        bar.set_postfix(success=f"{store.attrs['succeeded'] / store.attrs['attempted']:.0%}")
    bar.close()
    attrs = store.attrs
    return {k: attrs[k] for k in ("attempted", "succeeded")} | {"steps": store.n_steps}
