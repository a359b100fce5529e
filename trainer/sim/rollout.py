"""One closed-loop episode of a policy in ``GraspEnv``, and many of them on a process pool.

Each worker process builds its env and policy once (``spawn`` start: MuJoCo's GL context must not be
forked), then runs ``Job``s; results come back in submission order so stores stay deterministic.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from runtime.preprocess import crop_resize, restore_holes
from trainer.policies import Observation, make_policy
from trainer.sim.env import OBJECT_FROM_HAND, EnvConfig, GraspEnv
from trainer.sim.sensors import SceneSensor, SeededSensor, Sensor, make_sensor


@dataclass(frozen=True)
class Job:
    seed: int
    kind: str


def schedule(kinds: tuple[str, ...], seed: int, episodes: int, start: int = 0) -> list[Job]:
    """Episodes ``start..episodes-1`` of a run: episode i has seed ``seed + i`` and cycles through ``kinds``,
    so two runs with the same kinds and seeds meet the same scenes (``trainer compare`` pairs them)."""
    return [Job(seed + i, kinds[i % len(kinds)]) for i in range(start, episodes)]


@dataclass
class Rollout:
    seed: int
    kind: str
    success: bool
    steps: int
    episode: dict
    camera_K: np.ndarray
    camera_extrinsics: np.ndarray
    frames: dict[str, list[np.ndarray]] = field(default_factory=dict)
    """When recording: per step ``depth``, ``state``, ``action`` (and ``rgb``; with a sensor,
    ``depth_sensor``: the frame it showed the policy), observed before acting."""
    closed_at: tuple[int, np.ndarray] | None = None
    """The step the policy first commanded the gripper shut, and the object's position from the grasp site
    then (m, world frame): how far from the object a grasp was tried. None if it never closed."""


def start_episode(env: GraspEnv, policy, job: Job, sensors: Iterable[Sensor | None] = ()) -> dict:
    """Reset the env to ``job``, every sensor to its seed (same scene, same noise) and the policy to the
    episode; returns the env's reset info. An episode so depends on its job alone, not on the jobs its worker
    ran before it."""
    _, info = env.reset(seed=job.seed, options={"kind": job.kind})
    for sensor in sensors:
        if isinstance(sensor, SceneSensor):
            sensor.reset(env.world, job.seed)
        elif isinstance(sensor, SeededSensor):
            sensor.reseed(job.seed)
    policy.reset(info)
    return info


def expert_scenes(env: GraspEnv, kinds: tuple[str, ...], episodes: int, steps: tuple[int, ...], seed: int,
                  sensors: Iterable[Sensor | None] = ()) -> Iterator[tuple[int, int, dict]]:
    """The scripted expert through ``episodes`` episodes (seeds ``seed``.., kinds in turn), pausing at each of
    ``steps``: yields (episode, step, the env's info) with the world in that state. An episode that ends
    before a step yields only the steps it reached."""
    sensors = list(sensors)
    for i, job in enumerate(schedule(kinds, seed, episodes)):
        expert = make_policy("scripted")
        info = start_episode(env, expert, job, sensors)
        obs = env.observation()
        for step in range(max(steps) + 1):
            if step in steps:
                yield i, step, info
            obs, _, terminated, truncated, info = env.step(expert.act(Observation(obs, None, info["state"])))
            if terminated or truncated:
                break


def run_episode(env: GraspEnv, policy, job: Job, *, record: bool = False, sensor: Sensor | None = None,
                restore: str = "none", action_noise: float = 0.0) -> Rollout:
    """Reset to ``job``, act until the episode ends; the sensor maps clean depth to what the policy sees,
    after the runtime's hole restoration ``restore``. ``action_noise`` > 0 executes each action with that
    much Gaussian noise on its joints (seeded by the job) while recording the policy's own action: DART."""
    info = start_episode(env, policy, job, (sensor,))
    rng = np.random.default_rng([job.seed, 0xDA27])
    rollout = Rollout(job.seed, job.kind, False, 0, info["episode"], env.world.intr.K,
                      env.world.camera_extrinsics())
    if record:
        extra = (["rgb"] if "rgb" in info else []) + (["depth_sensor"] if sensor is not None else [])
        rollout.frames = {k: [] for k in ("depth", "state", "action", *extra)}
    obs = env.observation()
    while True:
        depth = info.get("depth")
        observation = Observation(obs, partial(observe, sensor, env, depth, restore), info["state"])
        action = np.asarray(policy.act(observation), np.float32)
        if rollout.closed_at is None and action[7] > 0:
            rollout.closed_at = (rollout.steps, obs[OBJECT_FROM_HAND].copy())
        if record:
            values = {"depth": depth, "state": info["state"], "action": action, "rgb": info.get("rgb")}
            # the sensor's frame is the one the policy read (made now if it did not read one)
            for key, frames in rollout.frames.items():
                frames.append(observation.depth if key == "depth_sensor" else values[key])
        obs, _, terminated, truncated, info = env.step(perturb(action, action_noise, rng))
        rollout.steps += 1
        if terminated or truncated:
            rollout.success = bool(info["success"])
            return rollout


def perturb(action: np.ndarray, noise: float, rng: np.random.Generator) -> np.ndarray:
    """DART (Laskey et al. 2017): a teacher whose executed joint commands are noisy visits the states a
    student's errors lead to, and its recorded actions say how to recover from them. The gripper command
    is left alone; joints stay in the action range [-1, 1]."""
    if not noise:
        return action
    out = action.copy()
    out[:7] = np.clip(action[:7] + rng.normal(0.0, noise, 7), -1.0, 1.0)
    return out


def observe(sensor: Sensor | None, env: GraspEnv, depth: np.ndarray | None, restore: str
             ) -> np.ndarray | None:
    """What the policy sees: clean depth through the sensor, or a scene sensor's stream cropped to the
    episode's window as the runtime crops a camera frame; then the runtime's hole restoration."""
    if isinstance(sensor, SceneSensor):
        seen = crop_resize(sensor.stream(env.world), env.spec, env.world.episode.crop_window)
    elif depth is None:
        return None
    else:
        seen = depth if sensor is None else sensor(depth)
    return restore_holes(seen, restore)


_WORKER: dict = {}


def _init(config: EnvConfig, policy_spec: str, record: bool, sensor_spec: str, restore: str,
          action_noise: float) -> None:
    # "clean" is no sensor model: the policy reads the env's depth, and a recording has nothing to add
    sensor = None if sensor_spec == "clean" else make_sensor(sensor_spec)
    _WORKER.update(env=GraspEnv(config), policy=make_policy(policy_spec), record=record, sensor=sensor,
                   restore=restore, action_noise=action_noise)


def _work(job: Job) -> Rollout:
    w = _WORKER
    return run_episode(w["env"], w["policy"], job, record=w["record"], sensor=w["sensor"],
                       restore=w["restore"], action_noise=w["action_noise"])


def rollouts(config: EnvConfig, policy_spec: str, jobs: Iterable[Job], *, workers: int = 1,
             record: bool = False, sensor_spec: str = "clean", restore: str = "none",
             action_noise: float = 0.0) -> Iterator[Rollout]:
    """Run ``jobs`` in order; ``workers`` > 1 uses that many processes, each building its own env,
    policy and sensor from the specs."""
    initargs = (config, policy_spec, record, sensor_spec, restore, action_noise)
    yield from in_workers(_init, initargs, _work, jobs, workers, _WORKER)


def in_workers(init: Callable, initargs: tuple, work: Callable, jobs: Iterable, workers: int,
               state: dict) -> Iterator:
    """``work(job)`` for each job, results in order: in this process, or in ``workers`` spawned ones, each
    set up once by ``init(*initargs)`` (which puts its env, as "env", into the module dict ``state``)."""
    if workers <= 1:
        init(*initargs)
        try:
            yield from map(work, jobs)
        finally:
            state.pop("env").close()
        return
    ctx = mp.get_context("spawn")
    with ctx.Pool(workers, initializer=_init_or_keep, initargs=(init, initargs)) as pool:
        yield from pool.imap(partial(_work_or_raise, work), jobs)


_INIT_ERROR: dict = {}
"""A worker's setup error (a policy that cannot be loaded), raised by its first job: a pool whose initializer
raises starts new workers for ever; a job's error reaches the parent as one worker's would."""


def _init_or_keep(init: Callable, initargs: tuple) -> None:
    try:
        init(*initargs)
    except Exception as exc:  # kept whole and raised in the parent by _work_or_raise
        _INIT_ERROR["error"] = exc


def _work_or_raise(work: Callable, job):
    if "error" in _INIT_ERROR:
        raise _INIT_ERROR["error"]
    return work(job)
