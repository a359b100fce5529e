"""Diffusion Depth Generator (paper "DiffuDepGrasp", section III-B).

Learns a RealSense's artifacts (holes, edge dropouts, speckle) from unpaired real captures and grafts them
onto simulated depth. Everything works at the policy resolution given by ``runtime.preprocess``.

The package also holds the second seed system, Stable-Sim2Real's residual depth diffusion (``residual.py``,
``residual_fit.py``, ``discriminator.py``): it learns the sensor's depth minus the simulator's from paired
frames of the same views (``pairs.py``), on the same U-Net, DDPM loop and DDIM sampler.
"""
