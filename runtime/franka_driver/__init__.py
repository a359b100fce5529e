"""The robot-side driver: its own process, a ZeroMQ server in front of a Franka Panda. Safety (command expiry,
velocity clamp, joint margins, workspace box, gripper hysteresis) lives here, whatever the runtime sends.
"""
