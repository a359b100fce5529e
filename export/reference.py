"""The torch reference an exported graph must reproduce, and its record inside the policy file.

At export the eager loop (diffusers' DDIM steps over the checkpoint's network) runs once on seeded example
inputs and its actions are stored in the file's metadata under ``REFERENCE_KEY``. ``export.check`` on a clone,
where the checkpoint is not shipped, then still measures parity: onnxruntime on the same seeded inputs
against the recorded torch actions."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np

from runtime.metadata import PolicyMetadata

if TYPE_CHECKING:
    from trainer.student.model import StudentPolicy

REFERENCE_KEY = "diffudepgrasp.reference"
REFERENCE_SEED = 0


def example_feeds(meta: PolicyMetadata, seed: int = 0) -> dict[str, np.ndarray]:
    """Random inputs of the graph's static shapes: depth in [0, 1] with 10 % holes, state, start noise."""
    rng, shapes = np.random.default_rng(seed), meta.input_shapes()
    depth = rng.random(shapes["depth"], dtype=np.float32)
    depth[rng.random(shapes["depth"]) < 0.1] = meta.preprocess.invalid_value
    return {"depth": depth, "state": (rng.standard_normal(shapes["state"]) * 0.5).astype(np.float32),
            "noise": rng.standard_normal(shapes["noise"], dtype=np.float32)}


def reference_actions(policy: StudentPolicy, meta: PolicyMetadata,
                      feeds: dict[str, np.ndarray]) -> np.ndarray:
    """The eager torch loop the graph must reproduce: diffusers' DDIM steps, then robot units."""
    import torch

    from trainer.student.ddim import reference_scheduler

    sched = reference_scheduler(policy.config.train_timesteps, meta.ddim_steps, meta.ddim_spacing,
                                policy.config.prediction)
    depth, state, x = (torch.from_numpy(feeds[k]) for k in ("depth", "state", "noise"))
    with torch.no_grad():
        obs = policy.encode(depth, state)
        for t in sched.timesteps:
            x = sched.step(policy(x, t.expand(x.shape[0]), obs), t, x).prev_sample
        actions = policy.action_norm.unnormalise(x)
    actions[..., :7] *= meta.action_scale
    return actions.numpy()


def record(policy: StudentPolicy, meta: PolicyMetadata) -> str:
    """The metadata value holding the torch actions on the seeded example inputs."""
    actions = reference_actions(policy, meta, example_feeds(meta, REFERENCE_SEED))
    return json.dumps({"seed": REFERENCE_SEED, "actions": actions.tolist()})


def recorded(custom_metadata: dict[str, str]) -> tuple[int, np.ndarray] | None:
    """(seed, actions) recorded at export, or None for a file exported before references were recorded."""
    value = custom_metadata.get(REFERENCE_KEY)
    if value is None:
        return None
    doc = json.loads(value)
    return int(doc["seed"]), np.asarray(doc["actions"], dtype=np.float32)
