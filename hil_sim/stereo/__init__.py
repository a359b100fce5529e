"""The physics-grounded active-stereo sensor model ``stereo`` (a rasterised analogue of Zhang et al.,
T-RO 2023): IR pair synthesis from a dot projector, semi-global matching, D4xx-like holes and noise.

``StereoSensor`` is the model, ``StereoParams`` its numbers; ``python -m hil_sim.stereo`` fits them
against real D4xx captures (``calibrate``) and measures the cost per frame (``bench``).
"""

from hil_sim.stereo.params import DEFAULT_PARAMS, StereoParams, StereoParamsError
from hil_sim.stereo.sensor import StereoFrame, StereoSensor

__all__ = ["DEFAULT_PARAMS", "StereoFrame", "StereoParams", "StereoParamsError", "StereoSensor"]
