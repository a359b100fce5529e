"""The MuJoCo hardware-in-the-loop stand-in for the D455 and the Franka (``python -m hil_sim``)."""

import os

# MuJoCo picks its OpenGL backend when first imported, whoever imports it: headless EGL unless the user chose
# one (GLFW, its default, needs a display and fails on a server at the first render).
os.environ.setdefault("MUJOCO_GL", "egl")
