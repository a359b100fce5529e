"""Architecture and horizons of the student; stored as JSON inside every checkpoint."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields

PREDICTIONS = ("epsilon", "v_prediction")
PERCEPTIONS = ("", "depth", "privileged")


class StudentConfigError(ValueError):
    """A student configuration that cannot build a model (bad width, horizon, dims)."""


RETIRED = {"first_frame": False, "seen_turn": False, "seen_yaw": False, "fine_stride": 8, "geometric": False,
           "readout_global": True, "keypoint_values": 0}
"""Options of past experiments, retired once the recipe beat them or they lost theirs (issue 42; ``docs/
history.md``), with the value that meant "off". Checkpoints written while they existed record them, off in all
but those experiments' own."""


def _drop_retired(d: dict) -> None:
    """Remove the ``RETIRED`` fields from a saved configuration; one that is on is refused."""
    if used := [name for name, off in RETIRED.items() if d.pop(name, off) != off]:
        raise StudentConfigError(f"students trained with {', '.join(used)} are no longer supported (retired "
                                 "in issue 42)")


@dataclass(frozen=True)
class StudentConfig:
    """Defaults vs diffusion_policy (To=2, Ha=16, Hexec=8): we stack 3 depth frames as the paper does,
    keep Ha=16 and Hexec=8 (1.6 s predicted, 0.8 s executed at 10 Hz)."""

    width: int = 64
    """ResNet-18 base width: stage channels are width, 2w, 4w, 8w (64 = the standard ResNet-18)."""
    keypoints: int = 32
    """Learned keypoints of the encoder's spatial-softmax pooling (robomimic / diffusion_policy: 32)."""
    obs_horizon: int = 3
    """Depth frames stacked as input channels, oldest first."""
    action_horizon: int = 16
    """Ha: actions predicted per inference."""
    exec_horizon: int = 8
    """Actions executed from each chunk before re-planning."""
    state_dim: int = 8
    action_dim: int = 8
    state_features: int = 64
    """Output size of the joint-state MLP."""
    head_dims: tuple[int, ...] = (64, 128, 256)
    """Channels of the 1-D U-Net levels over the action chunk (diffusion_policy: 256, 512, 1024)."""
    step_features: int = 64
    """Size of the sinusoidal diffusion-step embedding."""
    train_timesteps: int = 100
    """DDPM steps used in training (squared-cosine schedule, as diffusion_policy)."""
    prediction: str = "epsilon"
    """What the denoiser predicts: "epsilon" (the noise, as diffusion_policy) or "v_prediction" (the velocity
    sqrt(a) noise - sqrt(1 - a) actions, Salimans & Ho 2022). Where the sample is nearly pure noise the
    epsilon loss barely weighs the actions; the velocity's loss there is the actions themselves, so the
    network must read them off its observation (measured: it does, where the observation shows them; it did
    not learn the first step's turn; docs/student.md "The first step's turn")."""
    hand_target: bool = False
    """The training-only object head also reads, from depth, where the hand is relative to the object:
    object minus grasp site in x, y and the grasp site's height above the table (3 more outputs)."""
    hand_pose: bool = False
    """The state encoder also reads the hand's pose (position and two axes of its frame) computed from the
    joint angles by the Panda's forward kinematics inside the network: the inputs stay (depth, state), and
    the head need not learn the arm's kinematics from 1000 demos (docs/student.md "The oracle")."""
    object_offset: bool = False
    """With ``hand_pose``: the state encoder also reads the object's horizontal offset from the hand, the
    object head's estimate (then part of the exported graph) minus the hand's position."""

    seen_offset: bool = False
    """With ``hand_target``: the state encoder also reads the object head's estimate of the object's offset
    from the hand, read off the depth image where both are seen (no camera-pose error, unlike the absolute
    position that ``object_offset`` starts from); then part of the exported graph."""

    perception: str = ""
    """How the action head learns where the object is. "depth": dense privileged perception
    (``trainer.student.perception``): keypoints at stride 8 supervised to the object's and the hand's pixels
    and a readout of the object's offset from the hand, grasp direction and size, which the head reads with
    the hand's pose; the recipe of ``trainer student recipe``. "privileged": the same head reading the true
    facts instead of depth (no encoder; the oracle, milestone M0; not exportable). "": the earlier students'
    object head and its options below."""
    fine_keypoints: int = 16
    """``perception="depth"``: keypoints of the fine map (the first two are the supervised ones)."""
    head_features: bool = True
    """``perception="depth"``: the action head reads the depth features beside the facts. False: it reads
    only what the privileged head (M0) reads (the facts, the joint state, the hand's pose), so that a head
    trained on the true facts can act on the readout (``trainer student compose``)."""
    perceptions: int = 1
    """``perception="depth"``, ``head_features`` off: depth perceptions, each its own encoder, whose facts the
    head reads averaged. Two readouts fitted apart err apart, so their mean aims closer than either
    (``trainer student compose --also``; ``docs/student.md``)."""

    def __post_init__(self) -> None:
        if self.prediction not in PREDICTIONS:
            raise StudentConfigError(f"prediction must be one of {PREDICTIONS}, got {self.prediction!r}")
        if self.perception not in PERCEPTIONS:
            raise StudentConfigError(f"perception must be one of {PERCEPTIONS}, got {self.perception!r}")
        earlier = [name for name in ("hand_target", "hand_pose", "object_offset", "seen_offset")
                   if getattr(self, name)]
        if self.perception and earlier:
            raise StudentConfigError(f"perception={self.perception!r} reads the hand pose and its own facts: "
                                     f"drop {', '.join(earlier)}")
        if self.fine_keypoints < 2:
            raise StudentConfigError(f"fine_keypoints must be >= 2 (two are supervised), got "
                                     f"{self.fine_keypoints}")
        if self.perceptions < 1:
            raise StudentConfigError(f"perceptions must be >= 1, got {self.perceptions}")
        if self.perceptions > 1 and (self.perception != "depth" or self.head_features):
            raise StudentConfigError("perceptions > 1 averages depth readouts for a head that reads only the "
                                     "facts: it needs perception='depth' and head_features off")
        if self.seen_offset and not self.hand_target:
            raise StudentConfigError("seen_offset needs hand_target (the head's offset outputs)")
        if self.object_offset and not self.hand_pose:
            raise StudentConfigError("object_offset needs hand_pose (the offset is from the hand)")
        if self.width < 8 or self.width % 8:
            raise StudentConfigError(f"width must be a positive multiple of 8, got {self.width}")
        if not self.head_dims or any(d < 8 or d % 8 for d in self.head_dims):
            raise StudentConfigError(f"head_dims must be multiples of 8, got {self.head_dims}")
        if self.action_horizon % 2 ** (len(self.head_dims) - 1):
            raise StudentConfigError(f"action_horizon {self.action_horizon} must be divisible by "
                                     f"2**{len(self.head_dims) - 1} for a {len(self.head_dims)}-level U-Net")
        if not (0 < self.exec_horizon <= self.action_horizon):
            raise StudentConfigError(f"exec_horizon {self.exec_horizon} must be in 1..{self.action_horizon}")
        for name in ("keypoints", "obs_horizon", "state_dim", "action_dim", "state_features", "step_features",
                     "train_timesteps"):
            if getattr(self, name) < 1:
                raise StudentConfigError(f"{name} must be >= 1, got {getattr(self, name)}")

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> StudentConfig:
        d = json.loads(text)
        _drop_retired(d)
        unknown = set(d) - {f.name for f in fields(cls)}
        if unknown:
            raise StudentConfigError(f"unknown student config fields {sorted(unknown)}")
        if "head_dims" in d:
            d["head_dims"] = tuple(d["head_dims"])
        return cls(**d)
