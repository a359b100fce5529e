"""``python -m trainer student recipe``: the student that grasps, from nothing, in resumable stages.

    demos     the reactive expert's episodes, every frame labelled (round 0: ``trainer.student.dagger``)
    fit       the student on every labelled step so far (round 0 from scratch or ``--init``,
              then from the last round's)
    export    the student -> student.onnx (a depth student, composed with ``--head`` when given; the next
              round's learner, the shipped file)
    dagger    the learner's own episodes labelled by the expert (rounds 1..R, beta halved each round)
    hover     with ``--hover-episodes``: the head (``--head``) drives on facts offset by ``--hover-cm``, the
              expert labels every state; in every fit
    readout   a depth student's readout errors on frames it was not trained on: the next round's, and the
              last student's own episodes (seeds 30000..): fit/roundR/readout.json (milestone M1)
    curve     held-out success after each fit (seeds 20000..): learning_curve.csv and .png
    evaluate  the last round's student on seen and unseen kinds (seeds 10000..): fit/roundR/eval_seen.json
              and eval_unseen.json

Artifacts live in ``--out`` (default: ``$DIFFUDEPGRASP_HOME/recipe/NAME``, else
``~/.cache/diffudepgrasp/recipe/NAME``), outside any checkout, so a fresh clone resumes where the last one
stopped: each stage is skipped once its output is complete, and a stage cut off half way resumes (stores from
their last episode, fits from their last checkpoint). ``recipe.json`` there records the settings, which a
resume must repeat, except those in ``RESUMABLE`` (workers, precision, more rounds, longer rounds to come...).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path

import torch

from hil_sim.objects import GROUPS, select_kinds
from runtime.preprocess import DepthSpec
from trainer.argspec import add_dataclass_args, from_args
from trainer.dataset import DatasetError, DemoStore
from trainer.eval.success import evaluate
from trainer.menu import command_line
from trainer.sim.env import EnvConfig
from trainer.sim.sensors import make_sensor
from trainer.student import checkpoint
from trainer.student.checkpoint import TrainingInfo
from trainer.student.compose import compose
from trainer.student.config import StudentConfig
from trainer.student.dagger import RoundSpec, collect_round
from trainer.student.distill import DistillConfig, device, distill, parse_shares
from trainer.student.readout import measure
from trainer.student.steps import LabelledSteps
from trainer.student.train import CKPT_NAME

ROUND_SEED = 1_000_000
"""Round r's episodes use seeds ROUND_SEED + r * 100_000..: apart from the curve's and the evaluation's."""
CURVE_SEED = 20_000
HELD_OUT_SEED = 30_000
HOVER_SEED = 40_000
EVAL_SEED = 10_000


@dataclass(frozen=True)
class RecipeConfig:
    perception: str = "depth"
    """depth (the product: a depth student, exported to ONNX) | privileged (the head on true facts: M0)."""
    demos: int = 400
    """The expert's episodes (round 0)."""
    rounds: int = 4
    """DAgger rounds after round 0."""
    round_episodes: int = 100
    """Learner episodes per round."""
    beta: float = 0.5
    """Share of round 1's steps the expert executes; halved each round."""
    fit_steps: int = 12000
    """Optimiser steps of round 0's fit (from scratch, the head on true facts: 61 % seen after 3000 steps,
    92 % after 12000; docs/student.md "The recipe"; from a 128 x 96 depth student's weights at 192 x 144,
    1500)."""
    round_steps: int = 4000
    """Optimiser steps of each later round's fit, from the last round's weights, on all data so far."""
    init: str = ""
    """A depth student's checkpoint whose weights round 0's fit starts from instead of from scratch: one of
    the same model settings, at any ``resolution`` (the encoder pools by spatial softmax over image
    coordinates in [-1, 1] and by a mean, so no weight's shape depends on the image's)."""
    head_features: bool = True
    """The depth student's head reads the encoder's features beside the facts (``StudentConfig``). False: only
    the facts, the joint state and the hand's pose, as a composed student's head does, so that only the labels
    teach the encoder; a composed student (``python -m export.recover`` of a shipped file) is then an
    ``init``."""
    batch: int = 128
    lr: float = 3e-4
    width: int = 16
    """ResNet-18 base width of a depth student."""
    head_dims: tuple[int, ...] = (32, 64, 128)
    state_features: int = 128
    exec_horizon: int = 4
    prediction: str = "v_prediction"
    resolution: str = "128x96"
    """The policy's depth, WIDTHxHEIGHT of the same crop."""
    head: str = ""
    """A privileged student's checkpoint (M0: ``--perception privileged``, the head trained on the true
    facts). Each depth student is then composed with its head (``trainer student compose``) before export,
    so the learner, the curve and the shipped file act with M0's head on the readout; the fits teach
    perception."""
    objects: str = "seen"
    """The kinds the training episodes (demos, rounds, hover) draw from: a comma list of groups and kinds
    (``seen``; ``train``, the seen kinds and 24 procedural shapes, ``hil_sim.objects.SHAPES``). The curve and
    the evaluation keep the seen and unseen kinds. M0 on ``train`` (1000 demos) against M0 on ``seen``: unseen
    82.2 against 67.8 % (37 episodes won, 11 lost; the can 0 -> 53 %), seen 91.7 against 90.6 %."""
    round_objects: str = ""
    """The kinds the DAgger rounds' learner episodes draw from ("" = ``objects``): rounds still to come may
    change it. The demos give the seen kinds ~20 % of ``train``'s scenes, and the readout memorises the
    scenes it trained on (``docs/history.md``, 2026-11-29): ``seen`` rounds give those kinds more scenes;
    ``seen,squares`` adds round-in-plan boxes as tall as the can, which the readout otherwise reads as
    elongated (2026-11-30)."""
    hover_episodes: int = 0
    """Episodes driven by ``head`` on the true facts offset by ``hover_cm`` in a random horizontal direction
    (fixed per episode), every state labelled by the expert (``data/hover.zarr``, in every fit). They hold
    what the other stores seldom do and the readout misses most: the hand near the object but 1-2 cm beside
    it (expert and learner frames near the object are mostly on target, so the readout learned to say
    "nearly there" there: ``docs/history.md``, 2026-11-27). Round 4 with 100 of them (and its own round's
    data) against round 3, same 180 seeds: 85.6 against 79.4 % seen (17 episodes won, 6 lost)."""
    hover_cm: float = 1.5
    """How far beside the object (cm) the head aims in the hover episodes: inside the 0.7-2 cm band where the
    readout reports least of the offset (``readout.OFF_TARGET_M``)."""
    shift_px: int = 0
    """Training stacks shifted by up to this many pixels, their pixel labels alike
    (``DistillConfig.shift_px``)."""
    near_loss: float = 0.0
    """Weight of the readout's offset error relative to the distance to the object
    (``DistillConfig.near_loss``)."""
    shares: tuple[str, ...] = ()
    """``GROUP=SHARE`` items: the share of each fit's batches drawn from a group's steps, the rest from the
    others' (``DistillConfig.shares``); rounds still to come may change them."""
    sensor: str = "clean"
    """The depth source the student learns on (``trainer.sim.sensors``: ``ddg``, ``ddg_nograft``,
    ``randnoise`` ...): every round's learner sees its frames, the stores keep them beside the clean ones, the
    fits read them, and the curve and the evaluation run under it. Table II's rows are recipes that differ in
    this alone (issue 45)."""
    ddim_steps: int = 4
    workers: int = 2
    """Rollout processes (collection and evaluation)."""
    threads: int = 0
    """torch threads of the fits on the CPU (0 = torch's default; 1 beside busy rollout workers)."""
    precision: str = "fp32"
    """The fits' forward arithmetic, fp32 or bf16 (``DistillConfig.precision``; a resume may change it)."""
    curve_episodes: int = 30
    eval_episodes: int = 180
    seed: int = 0

    def student(self) -> StudentConfig:
        return StudentConfig(perception=self.perception, width=self.width, head_dims=self.head_dims,
                             state_features=self.state_features, exec_horizon=self.exec_horizon,
                             prediction=self.prediction, head_features=self.head_features)

    def spec(self) -> DepthSpec:
        width, _, height = self.resolution.partition("x")
        return DepthSpec(out_width=int(width), out_height=int(height))

    def depth_source(self) -> str:
        """The frames the fits read (``steps.STORED``)."""
        return "gt" if self.sensor == "clean" else "sensor"

    def distill(self, steps: int) -> DistillConfig:
        return DistillConfig(steps=steps, batch=self.batch, lr=self.lr, shift_px=self.shift_px,
                             near_loss=self.near_loss, shares=self.shares, precision=self.precision,
                             seed=self.seed)


def stored_settings(path: Path) -> dict:
    """A recipe's ``recipe.json``, with the defaults of the settings added since it was written."""
    defaults = json.loads(json.dumps(asdict(RecipeConfig())))
    return {**defaults, **json.loads(path.read_text())}


def default_home() -> Path:
    """Where long-lived artifacts live: ``$DIFFUDEPGRASP_HOME``, else the user's cache directory."""
    home = os.environ.get("DIFFUDEPGRASP_HOME")
    return Path(home) if home else Path.home() / ".cache" / "diffudepgrasp"


class Recipe:
    """The stages over one folder; ``run()`` does what is not done yet."""

    def __init__(self, out: Path, cfg: RecipeConfig) -> None:
        self.out, self.cfg = out, cfg
        self.env = EnvConfig(objects=select_kinds(cfg.objects), render_depth=cfg.perception == "depth",
                             depth=cfg.spec())
        self.dev = device()

    def run(self) -> dict:
        self._settings()
        if self.cfg.threads:
            torch.set_num_threads(self.cfg.threads)
        self.hover()  # the head's episodes depend on no round: collected first, in every fit
        for r in range(self.cfg.rounds + 1):
            self.collect(r)
            if r:
                self.readout(r - 1, partial(self.store, r))
            self.fit(r)
            self.curve(r)
        self.readout(self.cfg.rounds, self.held_out)  # the held-out episodes collected only if it is not done
        return self.evaluate()

    # --- stages -------------------------------------------------------------------------------------
    def collect(self, r: int) -> None:
        c = self.cfg
        if self.measured(r):
            return
        learner = "" if r == 0 else self.learner(r - 1)
        spec = RoundSpec(learner=learner, beta=c.beta * 0.5 ** (r - 1) if r else 0.0,
                         horizon=c.student().action_horizon, sensor=c.sensor)
        episodes = c.demos if r == 0 else c.round_episodes
        env = self.env if r == 0 or not c.round_objects else replace(self.env,
                                                                    objects=select_kinds(c.round_objects))
        if self._episodes(self.store(r)) < episodes:
            tally = collect_round(self.store(r), env, spec, episodes=episodes,
                                  seed=ROUND_SEED + r * 100_000, workers=c.workers)
            self._log(f"round {r} data", tally)

    def hover(self) -> None:
        c = self.cfg
        if c.hover_episodes and self._episodes(self.hover_store()) < c.hover_episodes:
            spec = RoundSpec(learner=f"oracle:{c.head}@{c.hover_cm:g}", horizon=c.student().action_horizon,
                             sensor=c.sensor)
            tally = collect_round(self.hover_store(), self.env, spec, episodes=c.hover_episodes,
                                  seed=HOVER_SEED, workers=c.workers)
            self._log("hover data", tally)

    def fit(self, r: int) -> None:
        if not self.measured(r):
            self.train(r)
        if self.cfg.perception == "depth" and not self.onnx(r).is_file():  # e.g. a round fitted on a GPU
            export(self.run_dir(r) / CKPT_NAME, self.onnx(r), self.cfg.ddim_steps,
                   Path(self.cfg.head) if self.cfg.head else None)

    def train(self, r: int) -> None:
        """Round ``r``'s weights: fitted from round ``r - 1``'s until they have the steps asked."""
        c = self.cfg
        steps = c.fit_steps if r == 0 else c.round_steps
        ckpt_path = self.run_dir(r) / CKPT_NAME
        if not (ckpt_path.is_file() and checkpoint.load(ckpt_path).step >= steps):
            data = LabelledSteps(self.stores(r), c.student().obs_horizon, c.student().action_horizon,
                                 depth=c.perception == "depth", device=self.dev,
                                 depth_source=c.depth_source())
            info = TrainingInfo(depth_spec=data.spec, action_scale=self.env.action_scale,
                                control_rate_hz=self.env.control_rate_hz, trained=True,
                                data={"recipe": str(self.out), "round": r, "steps": len(data),
                                      "command": command_line()})
            init = self.run_dir(r - 1) / CKPT_NAME if r else Path(c.init) if c.init else None
            self._log(f"round {r} fit", distill(data, self.run_dir(r), c.student(), c.distill(steps), info,
                                                init))

    def held_out(self) -> Path:
        """The last student's own episodes (no expert steps), labelled but never trained on."""
        c = self.cfg
        path = self.out / "data" / f"held_out_round{c.rounds}.zarr"  # more rounds later: another learner
        if self._episodes(path) < c.curve_episodes:
            spec = RoundSpec(learner=self.learner(c.rounds), horizon=c.student().action_horizon,
                             sensor=c.sensor)
            collect_round(path, self.env, spec, episodes=c.curve_episodes, seed=HELD_OUT_SEED,
                          workers=c.workers)
        return path

    def readout(self, r: int, store: Callable[[], Path]) -> None:
        """Milestone M1 for round ``r``'s depth student: its readout's errors on the store ``store()`` gives
        (called only if they are not measured yet), which holds the next round's (or the held-out) rollouts,
        frames it was not trained on."""
        path = self.readout_result(r)
        if self.cfg.perception != "depth" or path.is_file():
            return
        result = measure(self.run_dir(r) / CKPT_NAME, store(), self.dev, self.cfg.depth_source())
        path.write_text(json.dumps(result, indent=1))
        self._log(f"round {r} readout", {k: v for k, v in result.items() if k not in ("checkpoint", "store")})

    def curve(self, r: int) -> None:
        path = self.out / "learning_curve.csv"
        rows = read_curve(path)
        if any(int(row["round"]) == r for row in rows):
            return
        c = self.cfg
        result = evaluate(self.learner(r), GROUPS["seen"], c.curve_episodes, seed=CURVE_SEED,
                          workers=c.workers, sensor=c.sensor)
        self.curve_result(r).write_text(json.dumps(result, indent=2))
        store = DemoStore.open(self.store(r))
        rows.append({"round": r, "steps": sum(DemoStore.open(s).n_steps for s in self.stores(r)),
                     "round_success": round(store.attrs["succeeded"] / max(1, store.attrs["attempted"]), 4),
                     "held_out_success": result["success_rate"], "ci_low": result["ci95"][0],
                     "ci_high": result["ci95"][1], "episodes": c.curve_episodes})
        write_curve(path, rows)
        self._log(f"round {r} held-out", rows[-1])

    def evaluate(self) -> dict:
        c, results = self.cfg, {}
        for objects in ("seen", "unseen"):
            path = self.run_dir(c.rounds) / f"eval_{objects}.json"  # in the round's folder: a later round
            if not path.is_file():                                    # leaves this one's result in place
                result = evaluate(self.learner(c.rounds), GROUPS[objects], c.eval_episodes, seed=EVAL_SEED,
                                  workers=c.workers, sensor=c.sensor)
                path.write_text(json.dumps(result, indent=2))
            results[objects] = json.loads(path.read_text())
        return {k: {"success_rate": v["success_rate"], "ci95": v["ci95"]} for k, v in results.items()}

    # --- paths --------------------------------------------------------------------------------------
    def store(self, r: int) -> Path:
        return self.out / "data" / f"round{r}.zarr"

    def hover_store(self) -> Path:
        return self.out / "data" / "hover.zarr"

    def stores(self, r: int) -> list[Path]:
        """What round ``r``'s fit learns from."""
        hover = [self.hover_store()] if self.cfg.hover_episodes else []
        return [self.store(i) for i in range(r + 1)] + hover

    def run_dir(self, r: int) -> Path:
        return self.out / "fit" / f"round{r}"

    def measured(self, r: int) -> bool:
        """Whether the curve has measured round ``r``: then it keeps its data and weights, whatever episodes
        and steps are asked now, since what came after rests on them."""
        return self.curve_result(r).is_file()

    def curve_result(self, r: int) -> Path:
        """Round ``r``'s learner measured by the curve: written once its fit is final."""
        return self.run_dir(r) / "held_out.json"

    def readout_result(self, r: int) -> Path:
        return self.run_dir(r) / "readout.json"

    def onnx(self, r: int) -> Path:
        return self.run_dir(r) / "student.onnx"

    def learner(self, r: int) -> str:
        """The policy spec of round ``r``'s student."""
        if self.cfg.perception == "depth":
            return f"student:{self.onnx(r)}"
        return f"oracle:{self.run_dir(r) / CKPT_NAME}"

    # --- bookkeeping --------------------------------------------------------------------------------
    def _settings(self) -> None:
        path = self.out / "recipe.json"
        self.out.mkdir(parents=True, exist_ok=True)
        mine = json.loads(json.dumps(asdict(self.cfg)))
        if path.is_file():
            kept = stored_settings(path)
            changed = {k: (kept.get(k), v) for k, v in mine.items()
                       if k not in RESUMABLE and kept.get(k) != v}
            if changed:
                raise ValueError(f"{self.out} was made with other settings {changed}: repeat them or use "
                                 "another --out")
        path.write_text(json.dumps(mine, indent=1))

    @staticmethod
    def _episodes(path: Path) -> int:
        try:
            return int(DemoStore.open(path).attrs["attempted"])
        except DatasetError:
            return 0

    def _log(self, what: str, summary: dict) -> None:
        line = json.dumps({"stage": what, **summary})
        print(line, flush=True)
        with open(self.out / "log.jsonl", "a") as f:
            f.write(line + "\n")


RESUMABLE = {"workers", "threads", "precision", "curve_episodes", "eval_episodes", "rounds", "round_steps",
             "round_episodes", "round_objects", "shares"}
"""Settings a resume may change: how the work is spread and computed, how much is measured, how many more
rounds, and how many episodes the rounds still to come collect and how long they fit (a round the curve has
measured keeps its data and weights), the kinds they draw and the shares their fits weigh them by.
Precision is one: round 4 of the same recipe fitted in bf16 and in fp32 from the same round 3, same data and
seeds, grasped 78.3 / 61.7 % against 75.6 / 65.0 % (paired 11 / 6 seen, 8 / 14 unseen; neither clears)."""


def check_shares(cfg: RecipeConfig, resumed: bool) -> None:
    """Misspelt groups found now, not after the demos; in a new folder also shares of groups its episodes
    never draw (a resumed recipe's earlier rounds may have drawn other kinds: its fits check their steps)."""
    drawn = set(select_kinds(cfg.objects)) | set(select_kinds(cfg.round_objects or cfg.objects))
    for name in parse_shares(cfg.shares):
        if not (drawn & set(select_kinds(name)) or resumed):
            raise ValueError(f"--shares names {name}, which neither --objects nor --round-objects draws")


def export(ckpt: Path, out: Path, ddim_steps: int, head: Path | None = None) -> None:
    """``python -m export``, in its own process (trainer does not import export: export imports trainer).
    With ``head`` the depth student is first composed with that privileged head (``composed.pt`` beside
    ``ckpt``), so the exported student acts with M0's head on this fit's readout."""
    if head is not None:
        composed = ckpt.parent / "composed.pt"
        checkpoint.save(composed, compose(checkpoint.load(ckpt), checkpoint.load(head)))
        ckpt = composed
    subprocess.run([sys.executable, "-m", "export", str(ckpt), "--ddim-steps", str(ddim_steps), "--out",
                    str(out)], check=True, stdout=subprocess.DEVNULL)


def read_curve(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def write_curve(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot_curve(rows, path.with_suffix(".png"))


def plot_curve(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rounds = [int(r["round"]) for r in rows]
    rate = [100 * float(r["held_out_success"]) for r in rows]
    low = [100 * float(r["ci_low"]) for r in rows]
    high = [100 * float(r["ci_high"]) for r in rows]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.fill_between(rounds, low, high, alpha=0.25, label="95 % Wilson interval")
    ax.plot(rounds, rate, "o-", label="held-out success (learner alone)")
    ax.plot(rounds, [100 * float(r["round_success"]) for r in rows], "s--", alpha=0.6,
            label="the round's own episodes (with beta)")
    ax.set(xticks=rounds, xlabel="DAgger round (0 = expert demos only)", ylabel="success, %", ylim=(0, 100),
           title=f"student learning curve ({rows[-1]['episodes']} held-out episodes per round)")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer student recipe", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, help="the recipe's folder (default: the cache directory, see above)")
    p.add_argument("--name", default="student", help="folder name under the cache directory's recipe/")
    add_dataclass_args(p, RecipeConfig)
    args = p.parse_args(argv)
    cfg = from_args(RecipeConfig, args)
    try:
        cfg.student(), cfg.distill(cfg.fit_steps)
        if cfg.head and cfg.perception != "depth":
            raise ValueError("--head composes a depth student's perception with a privileged head: it needs "
                             "--perception depth")
        if cfg.sensor != "clean" and cfg.perception != "depth":
            raise ValueError(f"--sensor {cfg.sensor}: a privileged student reads no depth; it needs "
                             "--perception depth")
        make_sensor(cfg.sensor)  # a misspelt one fails here, in one line, not in the first worker
        if cfg.hover_episodes and not cfg.head:
            raise ValueError("--hover-episodes needs --head: the privileged head drives them")
        if cfg.head and not Path(cfg.head).is_file():  # found now, not by the first worker that loads it
            raise ValueError(f"--head {cfg.head}: no such checkpoint (M0 is a recipe of its own, "
                             "--perception privileged: docs/student.md)")
        if cfg.init and checkpoint.load(Path(cfg.init)).config != cfg.student():
            raise ValueError(f"--init {cfg.init} is a student of other settings than --width, --head-dims, "
                             "--state-features, --exec-horizon, --prediction and --head-features ask")
        out = args.out or default_home() / "recipe" / args.name
        check_shares(cfg, resumed=(out / "recipe.json").is_file())
        summary = Recipe(out, cfg).run()
    except (ValueError, DatasetError, OSError, subprocess.CalledProcessError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({"out": str(out), **summary}))
    return 0

