"""Training: the teacher's demos, the DDG, the student, and their measurements (``python -m trainer``)."""

import hil_sim  # noqa: F401  (its import sets MuJoCo's headless GL before any trainer module imports mujoco)
