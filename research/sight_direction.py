"""The composed policy told to close an object it reads as round along the camera's line of sight.

The readout errs along the line of sight (the object's depth extent is what the camera cannot see), and the
shipped student's fingers close across it: of its failed cans, wheels, lemons and breads the first close is
1.0-1.1 cm off across the pads and 0.2-0.4 cm along the closing axis (median; ``research/m0_failures.py``),
while the fingers forgive ~1.5 cm along their closing axis and ~0.7 cm across the pads. M0's head closes
across the narrow axis it is told, so here the direction it is told is the read one plus the line of sight
weighted by how round the object reads (1 - the read direction's length): an elongated read keeps its own, a
round read is to close along the sight. No fit: the same readout and head, paired with
``research/composed_policy.py`` (the composed policy as it reads) on the same seeds and arguments. Measured:
it loses grasps, the true offset given or not (``docs/history.md`` 2026-12-01): M0 never saw a grasp direction
on an object as wide as it is long.

    python -m export.recover models/student.onnx --out DIR     # DIR/student.pt (the readout), DIR/head.pt
    cp models/student.onnx DIR/ && ln -s student.pt DIR/ckpt.pt
    PYTHONPATH=. python research/sight_direction.py DIR/student.onnx DIR/head.pt \
        --objects can,wheel,persimmon --episodes 90 [--true offset] [--out J]
    PYTHONPATH=. python research/composed_policy.py DIR/student.onnx DIR/head.pt ...   # the same, as read
"""

from __future__ import annotations

import numpy as np

from research.composed_policy import GROUPS, ComposedPolicy, grasp_rate, parser, report
from research.own_frame_readout import SIGHT
from trainer.policies import Observation
from trainer.sim.labels import GRASP_YAW

SIGHT_DOUBLED = np.array([SIGHT[0] ** 2 - SIGHT[1] ** 2, 2 * SIGHT[0] * SIGHT[1]], np.float32)
"""(cos 2p, sin 2p) of the line of sight's yaw p: the grasp direction that closes the fingers along it."""


class SightPolicy(ComposedPolicy):
    """``ComposedPolicy`` whose read grasp direction leans to the line of sight as far as it reads round."""

    def read_facts(self, obs: Observation) -> np.ndarray:
        row = super().read_facts(obs)
        told = row[GRASP_YAW]
        roundness = max(0.0, 1.0 - float(np.linalg.norm(told)))
        row[GRASP_YAW] = told + roundness * SIGHT_DOUBLED
        return row


def main() -> None:
    p = parser(__doc__, "can,wheel,persimmon", 90)
    p.add_argument("--true", nargs="*", default=[], choices=sorted(GROUPS),
                   help="facts from the simulator, as composed_policy.py takes them")
    args = p.parse_args()
    policy = SightPolicy(args.student, args.head, tuple(args.true))
    report({"sight": True, "true": args.true, **grasp_rate(policy, args)}, args.out)


if __name__ == "__main__":
    main()
