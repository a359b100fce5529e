"""Gymnasium environment over ``hil_sim.world``: privileged observation, eq. 1 actions, eq. 2-7 reward."""
