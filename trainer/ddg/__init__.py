"""Diffusion Depth Generator (paper "DiffuDepGrasp", section III-B).

Learns a RealSense's artifacts (holes, edge dropouts, speckle) from unpaired real captures and grafts them
onto simulated depth. Everything works at the policy resolution given by ``runtime.preprocess``.
"""
