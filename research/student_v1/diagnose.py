"""Where a student's grasps go wrong (docs/student.md@b8caf57 "Where the closing error comes from"); seen
kinds, seeds 10000.., randomised episodes, one process:

python research/student_v1/diagnose.py tolerance --episodes 30   # the scripted expert aiming off on purpose
python research/student_v1/diagnose.py spread student:S.onnx --episodes 90   # what the closing offset follows
python research/student_v1/diagnose.py dart --sigma 0 0.3 --episodes 24       # the expert under DART noise
python research/student_v1/diagnose.py descent student:S.onnx --episodes 30   # where the hand strays off
python research/student_v1/diagnose.py locate student:S.onnx --checkpoint ckpt.pt   # its object estimate
                                                      [--sensor stereo]    # on what the sensor shows
python research/student_v1/diagnose.py parts scripted --checkpoint ckpt.pt --sensor stereo  # holes or values?
python research/student_v1/diagnose.py turn student:S.onnx --episodes 40     # the wrist's turn at the close
                                                      [--sensor stereo]
python research/student_v1/diagnose.py copycat S.onnx --demos D.zarr   # its wrist turn on the demos, by step
python research/student_v1/diagnose.py decides --checkpoint ckpt.pt --demos D.zarr --episodes 600

``tolerance`` says how precise a grasp must be; ``dart`` what the demos of ``trainer collect --action-noise``
look like; ``spread`` regresses a policy's closing offset (object minus grasp site when it first closes the
gripper) on each group of the episode's randomisation and prints the adjusted R^2 per group: which of them the
error follows. ``descent`` follows the hand before that close: how near it came to the object horizontally,
at what height, and how far it was when it closed. ``locate`` runs a student's training-only object head
(from ``--checkpoint``) on the frames of a policy's episodes (the student's own, or the expert's), binned by
the hand's height above the object until the close: whether its idea of where the object is degrades as the
hand comes near. ``parts`` splits what a sensor does to that estimate: its frames, its holes on clean depth,
its depth with the holes filled from clean depth, and clean depth, over the same steps. ``turn`` runs the
elongated seen kinds (banana, block: the same seeds as ``trainer evaluate``'s) and says, for the grasps that
succeed and those that fail, how far the fingers' closing axis is turned from the expert's grasp direction at
the first close (degrees, modulo 180) and how far the object is from the grasp site then. ``copycat`` runs
a student file on the demos' own frames and states (the elongated kinds, the first steps of each episode) and
correlates its wrist-turn action (joint 7, the first of each chunk) with the expert's, by step in the episode,
beside how well the wrist's angle off home alone predicts the expert's turn, and how well the object's yaw
from the fingers does: at step 0 neither the wrist's angle nor the frame history says which way the expert
turns, only the object's yaw in the image does. ``decides`` asks who decides the first step's turn in the
denoiser: at the episode's start (and at step 5), it noises the expert's chunk and the same chunk with the
wrist's turn flipped, with the same noise, to training timestep t, and says how often the network's
clean-chunk estimate turns the expert's way from each. Where both agree with the expert, the observation
decides; where the estimate follows the flipped chunk, the noisy chunk does, and in sampling that chunk is the
start noise.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mujoco
import numpy as np

from hil_sim.objects import GROUPS
from hil_sim.world import HOME_Q
from trainer.policies import depth_spec, make_policy
from trainer.sim.env import HAND_QUAT, OBJECT_FROM_HAND, OBJECT_POSITION, OBJECT_QUAT, EnvConfig, GraspEnv
from trainer.sim.rollout import Job, rollouts, run_episode
from trainer.teacher.scripted import ScriptedExpert

KINDS = GROUPS["seen"]
OFFSETS_CM = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0), (-2, 0, 0), (-4, 0, 0), (0, 1, 0),
              (0, 2, 0), (0, 3, 0), (0, 4, 0), (0, -2, 0), (0, -4, 0), (0, 0, 1), (0, 0, 2), (0, 0, 3)]
"""World x, y, z (z up: a grasp too high)."""
HEIGHT_BINS_CM = {"over 20": (20, np.inf), "10-20": (10, 20), "5-10": (5, 10), "under 5": (-np.inf, 5)}
"""locate: the hand's height above the object centre (cm), before it closes."""
GROUPS_OF_EPISODE = ("object_xy", "object_yaw", "crop_window", "camera_pos", "q0", "link_mass_scale",
                     "joint_friction", "joint_damping_scale", "joint_stiffness", "kind")


def jobs(episodes: int) -> list[Job]:
    """The evaluation episodes every measurement here shares (as ``trainer evaluate``'s defaults)."""
    return [Job(10_000 + i, KINDS[i % len(KINDS)]) for i in range(episodes)]


class OffsetExpert(ScriptedExpert):
    """The scripted expert aiming its grasp ``offset_cm`` away from where it should."""

    def __init__(self, offset_cm: tuple[float, float, float]) -> None:
        super().__init__()
        self.offset = np.asarray(offset_cm, float) / 100

    def _grasp_pose(self, priv: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos, frame = super()._grasp_pose(priv, rot)
        return pos + self.offset, frame


def tolerance(episodes: int) -> None:
    env = GraspEnv(EnvConfig(objects=KINDS, render_depth=False))
    for offset in OFFSETS_CM:
        wins = [run_episode(env, OffsetExpert(offset), job).success for job in jobs(episodes)]
        print(f"grasp aimed {offset} cm off: success {np.mean(wins):.2f} ({episodes} episodes)", flush=True)


def dart(episodes: int, sigmas: list[float]) -> None:
    env = GraspEnv(EnvConfig(objects=KINDS, render_depth=False))
    for sigma in sigmas:
        runs = [run_episode(env, ScriptedExpert(), job, action_noise=sigma) for job in jobs(episodes)]
        closes = np.array([r.closed_at[1] for r in runs if r.closed_at is not None]) * 100
        print(f"action noise {sigma}: success {np.mean([r.success for r in runs]):.2f}, "
              f"{np.mean([r.steps for r in runs]):.0f} steps, object - hand at the first close "
              f"mean {closes.mean(0).round(2)} std {closes.std(0).round(2)} cm ({episodes} episodes)",
              flush=True)


def features(episode: dict, group: str) -> list[float]:
    if group == "kind":
        return [float(episode["kind"] == k) for k in KINDS[1:]]
    if group == "object_yaw":  # grasps are symmetric under a half turn
        return [np.cos(2 * episode[group]), np.sin(2 * episode[group])]
    return list(np.atleast_1d(episode[group]))


def adjusted_r2(x: np.ndarray, y: np.ndarray) -> float:
    a = np.column_stack([x - x.mean(0), np.ones(len(y))])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    r2 = 1 - ((y - a @ coef) ** 2).sum() / ((y - y.mean()) ** 2).sum()
    return 1 - (1 - r2) * (len(y) - 1) / (len(y) - x.shape[1] - 1)


def spread(policy: str, episodes: int) -> None:
    runs = rollouts(EnvConfig(objects=KINDS, depth=depth_spec(policy)), policy, jobs(episodes))
    closed = [r for r in runs if r.closed_at is not None]
    offsets = np.array([r.closed_at[1] for r in closed]) * 100
    print(f"{len(closed)} of {episodes} episodes closed the gripper; object - hand at the first close, cm:")
    for axis, name in enumerate("xyz"):
        y = offsets[:, axis]
        fits = {g: adjusted_r2(np.array([features(r.episode, g) for r in closed]), y)
                for g in GROUPS_OF_EPISODE}
        print(f"  {name}: mean {y.mean():+.2f}, std {y.std():.2f}; adjusted R^2 of "
              + ", ".join(f"{g} {v:+.2f}" for g, v in fits.items()))


class Tracker:
    """Wraps a policy; records the object's offset from the grasp site (cm), its table position (m) and with
    ``frames`` the depth the policy was shown (after the sensor), at every step until the close."""

    def __init__(self, inner, frames: bool = False) -> None:
        self.inner, self.record_frames = inner, frames
        self.offsets, self.objects, self.frames, self.closed = [], [], [], False

    def reset(self, env_info: dict) -> None:
        self.offsets, self.objects, self.frames, self.closed = [], [], [], False
        self.inner.reset(env_info)

    def act(self, obs) -> np.ndarray:
        action = self.inner.act(obs)
        if not self.closed:
            self.offsets.append(obs.privileged[OBJECT_FROM_HAND] * 100)
            self.objects.append(obs.privileged[OBJECT_POSITION][:2])
            if self.record_frames:  # cached: the frame the policy read (made now if it skipped this step)
                self.frames.append(obs.depth)
            self.closed = bool(action[7] > 0)
        return action


def descent(policy: str, episodes: int) -> None:
    env, tracker = GraspEnv(EnvConfig(objects=KINDS, depth=depth_spec(policy))), Tracker(make_policy(policy))
    nearest, at_close = [], []
    for job in jobs(episodes):
        won = run_episode(env, tracker, job).success
        off = np.array(tracker.offsets)
        aside = np.linalg.norm(off[:, :2], axis=1)
        best = int(np.argmin(aside))
        nearest.append((aside[best], -off[best, 2]))
        at_close.append(aside[-1])
        print(f"seed {job.seed} {job.kind:7s} success {int(won)}: nearest {aside[best]:.2f} cm aside at "
              f"{-off[best, 2]:.1f} cm above (step {best}); {aside[-1]:.2f} cm aside at the close "
              f"(step {len(off) - 1}, {-off[-1, 2]:.1f} cm above)", flush=True)
    nearest_arr = np.array(nearest)
    print(f"median over {episodes} episodes: nearest {np.median(nearest_arr[:, 0]):.2f} cm aside at "
          f"{np.median(nearest_arr[:, 1]):.1f} cm above; at the close {np.median(at_close):.2f} cm aside")


ELONGATED = ("banana", "block")
"""turn: the seen kinds whose grasp direction matters (the others are round or square in plan view)."""


class TurnTracker(Tracker):
    """A Tracker that also records, until the close, how far the fingers' closing axis is turned from the
    scripted expert's grasp direction on the object as it lies (degrees, modulo 180)."""

    def __init__(self, inner) -> None:
        super().__init__(inner)
        self.expert, self.turns = ScriptedExpert(), []

    def reset(self, env_info: dict) -> None:
        super().reset(env_info)
        self.expert.reset(env_info)
        self.turns = []

    def act(self, obs) -> np.ndarray:
        if not self.closed:
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, obs.privileged[HAND_QUAT])
            rot = rot.reshape(3, 3)
            fingers = np.arctan2(rot[1, 1], rot[0, 1])
            off = self.expert._grasp_yaw(obs.privileged[OBJECT_QUAT], rot) - fingers
            self.turns.append(abs(np.degrees((off + np.pi / 2) % np.pi - np.pi / 2)))
        return super().act(obs)


def turn(policy: str, episodes: int, sensor_spec: str) -> None:
    from trainer.sim.sensors import make_sensor, reads_clean_depth

    env = GraspEnv(EnvConfig(objects=KINDS, depth=depth_spec(policy),
                             render_depth=reads_clean_depth(sensor_spec)))
    tracker, sensor = TurnTracker(make_policy(policy)), make_sensor(sensor_spec)
    rows = {True: [], False: []}
    for job in [j for j in jobs(3 * episodes) if j.kind in ELONGATED][:episodes]:
        won = run_episode(env, tracker, job, sensor=sensor).success
        start, turned, aside = tracker.turns[0], tracker.turns[-1], np.linalg.norm(tracker.offsets[-1][:2])
        rows[won].append((start, turned, aside))
        print(f"seed {job.seed} {job.kind:7s} success {int(won)}: fingers {start:.0f} deg from the expert's "
              f"direction at the start, {turned:.0f} deg and {aside:.2f} cm aside at the close", flush=True)
    for won, name in ((True, "succeeded"), (False, "failed")):
        if rows[won]:
            starts, turns, aside = np.array(rows[won]).T
            print(f"{len(turns)} {name}: fingers off by median {np.median(turns):.0f} deg (p90 "
                  f"{np.percentile(turns, 90):.0f}) at the close, {np.median(starts):.0f} at the start; "
                  f"{np.median(aside):.2f} cm aside")


COPYCAT_STEPS = {"0-1": (0, 2), "2-5": (2, 6), "6-11": (6, 12), "12-29": (12, 30)}
"""copycat: steps of each episode, from its start."""


def elongated_starts(data, store) -> np.ndarray:
    """The first steps of the banana and block episodes among ``data``'s (a ``DemoDataset`` of ``store``)."""
    kinds = store.kinds[: len(data.ends)]
    return np.array([s for s, k in zip(np.r_[0, data.ends[:-1]], kinds, strict=True) if k in ELONGATED], int)


def yaw_from_fingers(store, steps: int) -> np.ndarray:
    """Per demo step: twice the object's placed yaw from the fingers' closing axis (the grasp site's y axis)
    at the recorded joints, radians (a grasp turned by pi is the same grasp)."""
    from hil_sim.kinematics import ArmKinematics
    from trainer.student.data import per_step

    kinematics, state = ArmKinematics(), np.asarray(store.root["data/state"][:steps], np.float64)
    sites = [kinematics.site(np.r_[q[:7], 0.0, 0.0]) for q in state]  # fingers: no effect
    fingers = np.array([np.arctan2(rot[1, 1], rot[0, 1]) for _, rot in sites])
    return 2 * (per_step(store, "object_yaw", 1)[:steps, 0] - fingers)


def copycat(policy_path: str, demos: str) -> None:
    from trainer.dataset import DemoStore
    from trainer.student.data import DemoDataset
    from trainer.student.onnx_policy import StudentOnnxPolicy
    from trainer.student.probe import env_chunk

    policy = StudentOnnxPolicy(policy_path)
    data = DemoDataset.stacked_as(demos, "gt", policy.meta, policy.meta.preprocess)
    store = DemoStore.open(demos)
    starts = elongated_starts(data, store)
    doubled_yaw = yaw_from_fingers(store, len(data))
    rng = np.random.default_rng(0)
    for name, (lo, hi) in COPYCAT_STEPS.items():
        steps = [s + i for s in starts for i in range(lo, hi)]
        noise = [rng.standard_normal(policy.runtime.noise_shape, dtype=np.float32) for _ in steps]
        student = np.array([env_chunk(policy, data.depth_stack(i), data.state[i], n)[0, 6]
                            for i, n in zip(steps, noise, strict=True)])
        expert, wrist = data.action[steps, 6], data.state[steps, 6] - HOME_Q[6]
        print(f"steps {name} ({len(steps)}): wrist turn vs the expert's, correlation "
              f"{np.corrcoef(student, expert)[0, 1]:.2f}; mean |turn| {np.abs(student).mean():.2f} "
              f"(expert {np.abs(expert).mean():.2f}); the expert's turn vs the wrist's angle off home, "
              f"correlation {np.corrcoef(wrist, expert)[0, 1]:.2f}, vs sin(2 x the object's yaw from the "
              f"fingers) {np.corrcoef(np.sin(doubled_yaw[steps]), expert)[0, 1]:.2f}", flush=True)


DECIDES_T = (99, 95, 90, 75, 50)
"""decides: training timesteps at which the network's clean-chunk estimate is read."""


def decides(ckpt_path: str, demos: str, episodes: int) -> None:
    import torch

    from trainer.dataset import DemoStore
    from trainer.student import checkpoint
    from trainer.student.data import DemoDataset
    from trainer.student.ddim import training_scheduler

    ckpt = checkpoint.load(Path(ckpt_path))
    net, cfg = ckpt.policy().eval(), ckpt.config
    data = DemoDataset.stacked_as(demos, "gt", cfg, ckpt.info.depth_spec, episodes=episodes)
    starts = elongated_starts(data, DemoStore.open(demos))
    sched, gen = training_scheduler(cfg.train_timesteps, cfg.prediction), torch.Generator().manual_seed(0)
    print(f"{len(starts)} elongated episodes of {demos}; {cfg.prediction} prediction")
    for step in (0, 5):
        batch = data.batch(starts + step)
        flipped = batch.action.clone()
        flipped[..., 6] *= -1
        chunks = {"the expert's": batch.action, "the flipped": flipped}
        with torch.no_grad():
            obs = net.encode(batch.depth, batch.state)
            for t in DECIDES_T:
                noise = torch.randn(batch.action.shape, generator=gen)
                agree = [f"{name} chunk noised {turns_agree(net, sched, obs, c, noise, t, batch.action):.2f}"
                         for name, c in chunks.items()]
                print(f"step {step}, t={t} (signal {sched.alphas_cumprod[t].sqrt():.3f}): first turn the "
                      f"expert's way from " + ", from ".join(agree), flush=True)


def turns_agree(net, sched, obs, chunk, noise, t: int, expert) -> float:
    """How often the first wrist action of the network's clean estimate from ``chunk`` (env units) noised to
    ``t`` turns the way the ``expert``'s chunk does."""
    import torch

    from trainer.student.ddim import clean_and_noise

    a, k = sched.alphas_cumprod[t], torch.full((len(chunk),), t)
    noisy = sched.add_noise(net.action_norm.normalise(chunk), noise, k)
    x0, _ = clean_and_noise(noisy, net(noisy, k, obs), a.sqrt(), (1 - a).sqrt(), net.config.prediction)
    first = net.action_norm.unnormalise(x0.clamp(-1, 1))[:, 0, 6]
    return float((torch.sign(first) == torch.sign(expert[:, 0, 6])).float().mean())


class ObjectEstimate:
    """A student checkpoint's training-only object head, read in metres over an episode's frames."""

    def __init__(self, ckpt_path: str) -> None:
        from trainer.student import checkpoint
        from trainer.student.data import column_scale, training_targets

        self.ckpt = checkpoint.load(Path(ckpt_path))
        self.net = self.ckpt.policy().eval()
        self.mean, self.std = column_scale(training_targets(self.ckpt.info.data, False))

    def errors_cm(self, frames: list[np.ndarray], objects: list[np.ndarray]) -> np.ndarray:
        """Per step: how far the estimate from the frames stacked up to it lies from the object then."""
        import torch

        from runtime.preprocess import FrameStack, normalise
        from trainer.dataset import DEPTH_SCALE

        history = FrameStack(self.ckpt.config.obs_horizon)  # the runtime's stacking rule
        stacks = np.stack([history.push(normalise(frame, DEPTH_SCALE, self.ckpt.info.depth_spec))
                           for frame in frames])
        with torch.no_grad():
            guess = self.net.object_head(self.net.encoder(torch.from_numpy(stacks))).numpy()[:, :2]
        # against where the object is now, not where it was placed: a hand that strays may push it
        return np.linalg.norm(guess * self.std + self.mean - np.array(objects), axis=1) * 100


def summary(errors: list[float]) -> str:
    return f"{len(errors)} steps, object estimate off by median {np.median(errors):.2f} cm " \
           f"(p90 {np.percentile(errors, 90):.2f})"


def locate(policy: str, ckpt_path: str, episodes: int, sensor_spec: str) -> None:
    from trainer.sim.sensors import make_sensor, reads_clean_depth

    head, sensor = ObjectEstimate(ckpt_path), make_sensor(sensor_spec)
    env = GraspEnv(EnvConfig(objects=KINDS, depth=depth_spec(policy),
                             render_depth=reads_clean_depth(sensor_spec)))
    tracker = Tracker(make_policy(policy), frames=True)
    bins = {name: [] for name in HEIGHT_BINS_CM}
    for job in jobs(episodes):
        run_episode(env, tracker, job, sensor=sensor)
        errors = head.errors_cm(tracker.frames, tracker.objects)
        for error, offset in zip(errors, tracker.offsets, strict=True):
            bins[next(n for n, (lo, hi) in HEIGHT_BINS_CM.items() if lo <= -offset[2] < hi)].append(error)
    for name, errors in bins.items():
        if errors:
            print(f"hand {name} cm above the object: {summary(errors)}")


def sensor_parts(seen: np.ndarray, clean: np.ndarray) -> dict[str, np.ndarray]:
    """A sensor's frames split into what it loses and what it gets wrong, each on otherwise clean depth."""
    return {"the sensor's frames": seen,
            "its holes, clean depth elsewhere": np.where(seen == 0, 0, clean),
            "its depth, holes filled with clean depth": np.where(seen == 0, clean, seen),
            "clean depth": clean}


def parts(policy: str, ckpt_path: str, episodes: int, sensor_spec: str) -> None:
    from trainer.eval.paired_depth import wrong_depth
    from trainer.sim.sensors import make_sensor

    head, sensor = ObjectEstimate(ckpt_path), make_sensor(sensor_spec)
    env, tracker = GraspEnv(EnvConfig(objects=KINDS, depth=depth_spec(policy))), Tracker(make_policy(policy))
    errors, seen_all, clean_all = {}, [], []
    for job in jobs(episodes):
        run = run_episode(env, tracker, job, sensor=sensor, record=True)
        until_close = len(tracker.objects)  # the recording holds the frames the sensor showed the policy
        seen, clean = (np.stack(run.frames[key][:until_close]) for key in ("depth_sensor", "depth"))
        for name, frames in sensor_parts(seen, clean).items():
            errors.setdefault(name, []).extend(head.errors_cm(list(frames), tracker.objects))
        seen_all.append(seen)
        clean_all.append(clean)
    for name, errs in errors.items():
        print(f"{name}: {summary(errs)}")
    # judged in the policy's range: normalise clips the rest
    off = wrong_depth(np.concatenate(seen_all), np.concatenate(clean_all), head.ckpt.info.depth_spec)
    print(f"the sensor's depth in the policy's range, off clean depth by median {off['off_median_mm']:.0f} "
          f"mm (p90 {off['off_p90_mm']:.0f}, p99 {off['off_p99_mm']:.0f})")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=["tolerance", "spread", "dart", "descent", "locate", "parts", "turn",
                                    "copycat", "decides"])
    p.add_argument("policy", nargs="?", default="scripted",
                   help="a trainer policy spec (spread, descent, locate, parts, turn)")
    p.add_argument("--checkpoint", help="locate, parts: the student checkpoint whose object head is "
                   "measured; decides: the student whose denoiser is read")
    p.add_argument("--demos", help="copycat, decides: the demo store whose frames and states the student is "
                   "run on")
    p.add_argument("--episodes", type=int, default=30, help="episodes to run (decides: of --demos, 0 = all)")
    p.add_argument("--sensor", default="clean",
                   help="locate, parts, turn: the sensor the policy sees (as evaluate's: clean, stereo, ...)")
    p.add_argument("--sigma", type=float, nargs="+", default=[0.0, 0.3], help="dart: action noise levels")
    args = p.parse_args()
    if args.what in ("locate", "parts") and not args.checkpoint:
        p.error(f"{args.what} needs --checkpoint (the student whose object head is measured)")
    if args.what in ("copycat", "decides") and not args.demos:
        p.error(f"{args.what} needs --demos (the demo store to run the student on)")
    if args.what == "decides" and not args.checkpoint:
        p.error("decides needs --checkpoint (the student whose denoiser is read)")
    if args.what == "tolerance":
        tolerance(args.episodes)
    elif args.what == "dart":
        dart(args.episodes, args.sigma)
    elif args.what == "descent":
        descent(args.policy, args.episodes)
    elif args.what == "turn":
        turn(args.policy, args.episodes, args.sensor)
    elif args.what == "copycat":
        copycat(args.policy, args.demos)
    elif args.what == "decides":
        decides(args.checkpoint, args.demos, args.episodes)
    elif args.what in ("locate", "parts"):
        (locate if args.what == "locate" else parts)(args.policy, args.checkpoint, args.episodes, args.sensor)
    else:
        spread(args.policy, args.episodes)


if __name__ == "__main__":
    main()
