"""The robot-side driver: its own process, a ZeroMQ server in front of a Franka Panda (or hil_sim's MuJoCo
Panda). Safety (command expiry, velocity clamp, joint margins, workspace box, gripper hysteresis) lives here,
whatever the runtime sends. Run it with ``python -m runtime.franka_driver --backend franka|mujoco``.
"""
