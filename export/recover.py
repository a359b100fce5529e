"""``python -m export.recover``: a shipped ``student.onnx`` back into the student checkpoint(s) it
was exported from, so that training can go on from the file alone (a fresh machine has no cache).

The policy file names its network's settings (``training_data.student_config``) and holds every weight as a
graph initializer, but the exporter names some after the ops that read them (``onnx::Mul_4159``, a norm's
scale) and merges equal ones (an ``Identity`` node then gives the second name). Exporting a network of the
same settings whose every tensor holds distinct values tells which initializer is which tensor; the file's
initializers of those names are its weights. The recovered student must reproduce the file's actions on the
seeded example inputs (``export.reference``) or nothing is written.

A composed student (``trainer student compose``) also gives back its privileged head (M0) exactly: the head's
weights and normalisers are the composed student's, less the perception. Writes ``OUT/student.pt`` and, for a
composed file, ``OUT/head.pt``; a file of several perceptions (``compose --also``) gives each as a composed
student of one, the first as ``student.pt``, its partners as ``partner1.pt``, ...:

    python -m export.recover models/student.onnx --out DIR
    python -m trainer student recipe --init DIR/student.pt --no-head-features --head DIR/head.pt ...
    python -m trainer student compose --perception DIR/student.pt --also DIR/partner1.pt --head DIR/head.pt \
        --out C.pt
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from export.graph import portable, read_metadata, trace
from export.reference import REFERENCE_SEED, example_feeds, reference_actions
from runtime.metadata import MetadataError, PolicyMetadata
from trainer.student import checkpoint
from trainer.student.checkpoint import Checkpoint, TrainingInfo, sha256
from trainer.student.compose import perception_prefixes
from trainer.student.config import StudentConfig, StudentConfigError
from trainer.student.model import build_policy

PARITY_TOL = 1e-4
"""Largest action difference (robot units) between the file and the recovered torch student: export parity
is ~1e-6 (``export.check``); a wrongly placed tensor moves actions by far more."""


class RecoverError(ValueError):
    """A policy file whose weights cannot be recovered into a checkpoint."""


def recover(path: Path) -> tuple[dict[str, Checkpoint], float]:
    """``{"student": ...}``, and ``"head"`` for a composed student, from the policy file at ``path``; and the
    largest difference between the file's actions and the recovered student's on the reference inputs."""
    model = _load(path)
    try:
        meta = read_metadata(model)
    except MetadataError as exc:
        raise RecoverError(f"{path} is not a student policy file: {exc}") from None
    config = _config(path, meta)
    net = build_policy(config).eval()
    names = _initializer_names(config, meta)
    values = _initializers(model)
    missing = sorted(set(names) - set(values))
    if missing:
        raise RecoverError(f"{path}: its graph names its weights otherwise than this version's exporter does "
                           f"(no initializer {missing[0]!r}); recover it with the torch that exported it")
    shapes = net.state_dict()
    state = {key: _tensor(path, values[name], shapes[key], key) for name, key in names.items()}
    net.load_state_dict(state)
    error = _parity(path, net, meta)
    student = _student(path, meta, config, state)
    composed = student.info.data.get("composed")
    if composed is None:
        return {"student": student}, error
    return {**_perceptions(student), "head": _head(student, composed["head"])}, error


def _load(path: Path) -> onnx.ModelProto:
    try:
        return onnx.load(str(path))
    except OSError as exc:
        raise RecoverError(f"cannot read {path}: {exc}") from None
    except Exception as exc:  # protobuf's DecodeError and kin on a file that is not ONNX
        raise RecoverError(f"{path} is not an ONNX file ({type(exc).__name__})") from None


def _config(path: Path, meta: PolicyMetadata) -> StudentConfig:
    text = meta.training_data.get("student_config")
    if text is None:
        raise RecoverError(f"{path}: its metadata names no student_config (not from `python -m export`)")
    try:
        config = StudentConfig.from_json(text)
    except (StudentConfigError, json.JSONDecodeError, TypeError) as exc:
        raise RecoverError(f"{path}: its student_config is not this version's: {exc}") from None
    if config.perception != "depth":  # the earlier students' object head is trained but not exported
        raise RecoverError(f"{path}: only the recipe's depth students can be recovered, this one has "
                           f"perception={config.perception!r}")
    return config


def _initializer_names(config: StudentConfig, meta: PolicyMetadata) -> dict[str, str]:
    """{initializer name: state-dict key} of the export of a ``config`` student, found by giving each of its
    tensors distinct values."""
    probe = build_policy(config).eval()
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for tensor in probe.state_dict().values():
            tensor.copy_(torch.rand(tensor.shape, generator=gen) + 2.0)  # no zeros, ones or repeats
    by_value = {tensor.numpy().tobytes(): key for key, tensor in probe.state_dict().items()}
    names = {init.name: by_value.get(numpy_helper.to_array(init).tobytes())
             for init in trace(probe, meta).graph.initializer}
    names = {name: key for name, key in names.items() if key is not None}
    unplaced = set(probe.state_dict()) - set(names.values())
    if unplaced:
        raise RecoverError(f"the exporter folds {sorted(unplaced)[0]} into other constants: it cannot be "
                           "recovered")
    return names


def _tensor(path: Path, value: np.ndarray, like: torch.Tensor, key: str) -> torch.Tensor:
    if value.size != like.numel():
        raise RecoverError(f"{path}: the initializer for {key} holds {value.size} values, the network's "
                           f"{like.numel()}: exported by another version")
    return torch.from_numpy(value.copy()).reshape(like.shape)


def _initializers(model: onnx.ModelProto) -> dict[str, np.ndarray]:
    """Every initializer by name, with the names the exporter's ``Identity`` nodes give merged ones."""
    values = {init.name: numpy_helper.to_array(init) for init in model.graph.initializer}
    for node in model.graph.node:
        if node.op_type == "Identity" and node.input[0] in values:
            values[node.output[0]] = values[node.input[0]]
    return values


def _parity(path: Path, net: torch.nn.Module, meta: PolicyMetadata) -> float:
    import onnxruntime as ort

    feeds = example_feeds(meta, REFERENCE_SEED)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (actions,) = session.run(None, feeds)
    error = float(np.abs(reference_actions(net, meta, feeds) - actions).max())
    if not error <= PARITY_TOL:
        raise RecoverError(f"{path}: the recovered student's actions differ from the file's by {error:.2g} "
                           f"(> {PARITY_TOL:g}): not written")
    return error


def _student(path: Path, meta: PolicyMetadata, config: StudentConfig, state: dict) -> Checkpoint:
    kept = {k: v for k, v in meta.training_data.items()
            if k not in ("checkpoint", "checkpoint_sha256", "train_step", "student_config")}
    data = {**kept, "recovered_from": {"file": portable(str(Path(path).resolve())), "sha256": sha256(path),
                                       "checkpoint": meta.training_data.get("checkpoint", "")}}
    info = TrainingInfo(depth_spec=meta.preprocess, action_scale=meta.action_scale,
                        control_rate_hz=meta.control_rate_hz, trained=meta.trained, data=data)
    return Checkpoint(config, info, ema=state, model={k: v.clone() for k, v in state.items()},
                      step=int(meta.training_data.get("train_step", 0)))


def _perceptions(student: Checkpoint) -> dict[str, Checkpoint]:
    """``{"student": ...}`` for a composed student of one perception; for one of several, each perception
    with the head as a student of one (``student``, ``partner1``, ...), which compose back into it."""
    if student.config.perceptions == 1:
        return {"student": student}
    config = dataclasses.replace(student.config, perceptions=1)
    composed = {k: v for k, v in student.info.data["composed"].items() if k != "partners"}
    records = [composed["perception"], *student.info.data["composed"]["partners"]]
    out = {}
    for i, (own, record) in enumerate(zip(perception_prefixes(len(records)), records, strict=True)):
        state = _head_weights(student)
        state.update({"perception." + k.removeprefix(own): v.clone() for k, v in student.ema.items()
                      if k.startswith(own)})
        data = {**student.info.data, "composed": {**composed, "perception": record}}
        out["student" if i == 0 else f"partner{i}"] = Checkpoint(
            config, dataclasses.replace(student.info, data=data), ema=state,
            model={k: v.clone() for k, v in state.items()}, step=student.step)
    return out


def _head_weights(student: Checkpoint) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in student.ema.items() if not k.startswith(("perception.", "partners."))}


def _head(student: Checkpoint, record: dict) -> Checkpoint:
    """The privileged student a composed one took its head from: every tensor but the perceptions'."""
    config = dataclasses.replace(student.config, perception="privileged", head_features=True, perceptions=1)
    state = _head_weights(student)
    info = dataclasses.replace(student.info,
                               data={**record, "recovered_from": student.info.data["recovered_from"]})
    return Checkpoint(config, info, ema=state, model={k: v.clone() for k, v in state.items()},
                      step=int(record.get("steps", 0)))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m export.recover",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("model", type=Path, help="a policy file written by `python -m export` "
                   "(models/student.onnx)")
    p.add_argument("--out", type=Path, required=True, help="folder for student.pt (and head.pt, if composed)")
    args = p.parse_args(argv)
    try:
        recovered, error = recover(args.model)
    except (RecoverError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    written = {}
    for name, ckpt in recovered.items():
        written[name] = str(args.out / f"{name}.pt")
        checkpoint.save(args.out / f"{name}.pt", ckpt)
    config = json.loads(recovered["student"].config.to_json())
    print(json.dumps({"written": written, "max_abs_err": error, "config": config}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
