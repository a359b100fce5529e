"""The "takeover:ONNX" policy of ``trainer collect``: recovery demos from the states the student's own
errors lead to (the data of DAgger).

The exported student drives each episode up to a switch step drawn from the episode's seed, then the
``ReactiveExpert`` takes over and finishes the grasp; ``collect`` stores only the expert's part (from
``taught_from``). The expert takes over instead of relabelling every visited state as DAgger does, because
a student's label is a chunk of future actions, which only a rollout of the expert gives. The reactive
expert reads its phase off each observation, so it acts sensibly from any state, e.g. opens and starts
again after the student closed on air.
"""

from __future__ import annotations

import numpy as np

from trainer.policies import Observation
from trainer.student.onnx_policy import StudentOnnxPolicy
from trainer.teacher.scripted import ReactiveExpert

SWITCH_STEPS = (5, 50)
"""The student drives for a uniform number of steps in [5, 50): students close the gripper after 30-45."""


class TakeoverPolicy:
    def __init__(self, student_path: str) -> None:
        self.student = StudentOnnxPolicy(student_path)
        self.expert = ReactiveExpert()
        self.taught_from = 0
        self._step = 0

    def reset(self, env_info: dict) -> None:
        self.student.reset(env_info)
        self.expert.reset(env_info)
        self.taught_from = int(np.random.default_rng(env_info["episode"]["seed"]).integers(*SWITCH_STEPS))
        self._step = 0

    def act(self, obs: Observation) -> np.ndarray:
        driver = self.student if self._step < self.taught_from else self.expert
        self._step += 1
        return driver.act(obs)


def load(path: str) -> TakeoverPolicy:
    return TakeoverPolicy(path)
