"""``StereoParams``: every number of the active-stereo sensor model, validated, saved as JSON.

Geometry is the D455's (95 mm baseline, projector between the imagers). The free parameters that
``python -m hil_sim.stereo calibrate`` fits against real D4xx data are marked "(fitted)"; the shipped
values live in ``hil_sim/stereo_params.json``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path

DEFAULT_PARAMS = Path(__file__).resolve().parents[1] / "stereo_params.json"


class StereoParamsError(ValueError):
    """A sensor parameter out of its range, or a parameters file that cannot be used."""


@dataclass(frozen=True)
class StereoParams:
    render_scale: float = 0.5
    """Working resolution as 1/n of the 848x480 stream; depth is repeated back up to 848x480."""
    baseline_m: float = 0.095
    """Left-to-right imager distance of a D455."""
    projector_offset_m: float = 0.0475
    """Projector position right of the left imager (D455: between the imagers)."""
    projector_fov_scale: float = 1.3
    """Projector focal length = imager focal / this: its field of view covers the imagers'."""
    dot_spacing_px: float = 4.0
    """Mean distance between neighbouring projector dots as seen in the working image, pixels."""
    dot_sigma_px: float = 0.8
    """Gaussian radius of one dot in the working image, pixels."""
    ambient: float = 0.3
    """(fitted) Ambient IR irradiance relative to the peak of a projector dot at 1 m (projector power vs
    ambient light: the dots' contrast)."""
    exposure_level: float = 50.0
    """(fitted) Median IR level (0-255) that auto-exposure gives the lit scene, as a D4xx's auto-exposure."""
    read_noise: float = 1.0
    """Std of the imager's read noise, IR levels."""
    scene_albedo: float = 0.6
    """IR albedo of the table, floor and robot."""
    surface_texture: float = 0.0
    """(fitted) Passive IR texture of every surface (grain, print, wear): albedo x (1 + this x value noise in
    [-1, 1]). Under ambient light it gives matching something to lock on where the dots fade (far, grazing
    surfaces), as on real surfaces; 0 = perfectly uniform materials."""
    texture_cell_m: float = 0.015
    """Lattice spacing of that value noise, metres: ~1.5 working pixels at 2 m, so both imagers still
    resolve it on the far table (4 mm cells alias there: a 3 m wall kept 35 % of its depth, 15 mm 100 %)."""
    material_probs: tuple[float, float, float] = (0.5, 0.25, 0.25)
    """Chance that an episode's object is ordinary / dark / shiny."""
    block_size: int = 5
    """Matching window (odd), working pixels."""
    num_disparities: int = 64
    """Disparity search range (multiple of 16); sets the nearest measurable depth."""
    uniqueness_ratio: int = 10
    """SGBM: best cost must beat the second best by this many percent."""
    disp12_max_diff: int = 1
    """Left-right consistency check tolerance, pixels."""
    texture_threshold: float = 3.0
    """(fitted) Minimum standard deviation of the left IR image inside the matching window, levels."""
    min_correlation: float = 0.5
    """Minimum normalised cross-correlation of a match's left and right windows (D4xx score threshold)."""
    disparity_noise_px: float = 0.05
    """(fitted) Std of the spatially correlated disparity noise, working pixels."""
    noise_correlation_px: float = 2.0
    """Gaussian correlation length of that noise, working pixels."""
    shadow_tolerance: float = 0.01
    """A point is lit when within this relative depth of the first surface the projector sees."""

    def __post_init__(self) -> None:
        _check(0 < self.render_scale <= 1 and (1 / self.render_scale).is_integer(),
               f"render_scale must be 1/n, got {self.render_scale}")
        _check(self.block_size >= 3 and self.block_size % 2 == 1,
               f"block_size must be an odd number >= 3, got {self.block_size}")
        _check(self.num_disparities >= 16 and self.num_disparities % 16 == 0,
               f"num_disparities must be a positive multiple of 16, got {self.num_disparities}")
        for name in ("baseline_m", "projector_fov_scale", "dot_spacing_px", "dot_sigma_px", "exposure_level",
                     "noise_correlation_px", "texture_cell_m"):
            _check(getattr(self, name) > 0, f"{name} must be positive, got {getattr(self, name)}")
        for name in ("ambient", "read_noise", "texture_threshold", "disparity_noise_px", "shadow_tolerance",
                     "uniqueness_ratio", "disp12_max_diff"):
            _check(getattr(self, name) >= 0, f"{name} must be >= 0, got {getattr(self, name)}")
        _check(-1 <= self.min_correlation <= 1,
               f"min_correlation must be in [-1, 1], got {self.min_correlation}")
        _check(0 < self.scene_albedo <= 1, f"scene_albedo must be in (0, 1], got {self.scene_albedo}")
        _check(0 <= self.surface_texture < 1,
               f"surface_texture must be in [0, 1), got {self.surface_texture}")
        probs = self.material_probs
        _check(len(probs) == 3 and min(probs) >= 0 and abs(sum(probs) - 1) < 1e-6,
               f"material_probs must be 3 non-negative numbers summing to 1, got {probs}")

    def replace(self, **changes) -> StereoParams:
        return StereoParams(**{**asdict(self), **changes})

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> StereoParams:
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise StereoParamsError(f"unknown stereo parameters {sorted(unknown)} (known: {sorted(known)})")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    def save(self, path: Path, **extra) -> None:
        """Write the parameters (and ``extra`` keys such as the fit's provenance) as JSON."""
        path.write_text(json.dumps({"params": self.to_dict(), **extra}, indent=2) + "\n")

    @classmethod
    def load(cls, path: Path | str | None = None) -> StereoParams:
        """The parameters in ``path`` (default: the shipped, fitted ``hil_sim/stereo_params.json``)."""
        path = Path(path) if path else DEFAULT_PARAMS
        if not path.is_file():
            raise StereoParamsError(f"stereo parameters file {path} does not exist")
        try:
            doc = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise StereoParamsError(f"{path} is not JSON: {exc}") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("params"), dict):
            raise StereoParamsError(f"{path} has no 'params' object")
        return cls.from_dict(doc["params"])


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise StereoParamsError(message)
