"""``python -m trainer student refit``: a depth student refitted on labelled stores collected apart from any
recipe (``trainer student readout --store``), with chosen shares of each batch per object group: the recipe's
fit stage alone. The shipped file's partner readout (``trainer student compose --also``) is one.

    python -m trainer student refit --init REC/student.pt --stores A.zarr B.zarr --shares seen=0.45 \\
        squares=0.2 --steps 1200 --shift-px 6 --near-loss 1 --precision bf16 [--perception-only] \
        [--depth-source sensor [--teacher CLEAN.pt --teacher-loss W]] --out DIR

The network and the depth it sees are the init's (``python -m export.recover`` gives a shipped file's); the
fit's settings are ``DistillConfig``'s. ``--perception-only`` fits the readout alone, which is all a partner
readout keeps, on stores whose frames are labelled without the expert's chunks (``trainer student readout
--no-chunks``, ~4x faster to collect). ``--depth-source sensor`` fits on the frames a sensor showed the
learner (stores collected with ``trainer student readout --sensor ddg``, say); with ``--teacher``, a depth
student that reads clean depth is its feature teacher on the clean frames of the same steps
(``distill.FeatureTeacher``). Writes ``DIR/ckpt.pt`` and ``DIR/loss.png``; a refit cut off resumes from
``DIR``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from trainer.argspec import add_dataclass_args, from_args
from trainer.dataset import DatasetError
from trainer.student import checkpoint
from trainer.student.checkpoint import TrainingInfo
from trainer.student.distill import DistillConfig, FeatureTeacher, device, distill
from trainer.student.steps import STORED, LabelledSteps


def refit(init: Path, stores: list[Path], out: Path, cfg: DistillConfig, depth_source: str = "gt",
          teacher: Path | None = None) -> dict:
    """Fit ``init``'s student on ``stores``' ``depth_source`` frames (``steps.STORED``) into ``out``, with
    ``teacher`` reading the clean frames as its feature teacher if given; the fit's summary."""
    source = checkpoint.load(init)
    model = source.config
    if model.perception != "depth" or model.perceptions != 1:
        raise ValueError(f"--init must be a depth student of one perception, got perception="
                         f"{model.perception!r}, perceptions={model.perceptions}")
    data = LabelledSteps(stores, model.obs_horizon, model.action_horizon, depth=True,
                         chunks=not cfg.perception_only, device=device(), depth_source=depth_source,
                         teacher_source="gt" if teacher else None)
    if data.spec != source.info.depth_spec:
        raise ValueError(f"the stores hold depth as {data.spec}, --init sees {source.info.depth_spec}")
    guide = None if teacher is None else FeatureTeacher(_same_network(teacher, source).to(data.device), data)
    info = TrainingInfo(depth_spec=data.spec, action_scale=source.info.action_scale,
                        control_rate_hz=source.info.control_rate_hz, trained=True,
                        data={"depth_source": depth_source,
                              "refit": {"init": str(init), "stores": [str(s) for s in stores],
                                        "steps": len(data), "shares": list(cfg.shares),
                                        "teacher": str(teacher) if teacher else None}})
    return distill(data, out, model, cfg, info, init, guide)


def _same_network(path: Path, student: checkpoint.Checkpoint) -> torch.nn.Module:
    """The teacher's network, refused in one line unless its features are the student's (same perception
    network and depth)."""
    teacher = checkpoint.load(path)
    same = (teacher.config.perception == "depth" and teacher.config.width == student.config.width
            and teacher.config.keypoints == student.config.keypoints
            and teacher.config.fine_keypoints == student.config.fine_keypoints
            and teacher.config.obs_horizon == student.config.obs_horizon
            and teacher.info.depth_spec == student.info.depth_spec)
    if not same:
        raise ValueError(f"--teacher {path} must be a depth student of --init's perception network and depth")
    return teacher.policy()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m trainer student refit", description=__doc__.split("\n\n")[0])
    p.add_argument("--init", type=Path, required=True, help="the depth student to refit (its weights, "
                   "network and depth)")
    p.add_argument("--stores", type=Path, nargs="+", required=True, help="labelled stores to fit on")
    p.add_argument("--out", type=Path, required=True, help="folder for ckpt.pt and loss.png (resumed)")
    p.add_argument("--depth-source", choices=sorted(STORED), default="gt",
                   help="the frames to fit on: gt (clean), sensor (what `trainer student readout --sensor` "
                        "showed the learner) or a generator's (`trainer ddg generate`)")
    p.add_argument("--teacher", type=Path, help="a depth student that reads clean depth: its readout "
                   "features of the clean frames teach the fitted frames' (with --teacher-loss W > 0)")
    p.add_argument("--threads", type=int, default=0, help="torch threads on the CPU (0 = torch's default)")
    add_dataclass_args(p, DistillConfig)
    args = p.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        summary = refit(args.init, args.stores, args.out, from_args(DistillConfig, args), args.depth_source,
                        args.teacher)
    except (ValueError, OSError, DatasetError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(summary))
    return 0
