"""``StereoSensor``: the D455 as an active-stereo depth sensor over a ``World`` (a "scene sensor").

Per frame: render left imager, right imager and projector (``render``), synthesise the IR pair (``ir``),
match it (``match``), turn disparity into depth (z = f B / d, 1 mm units, 0 where matching failed) at
the working resolution and repeat pixels up to the 848x480 stream, so ``runtime.preprocess`` applies
unchanged. The object's IR material (ordinary / dark / shiny) is drawn per episode; every random draw
comes from the seed given to ``reset``, so a seed fixes the frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hil_sim.camera import Intrinsics, to_millimetres
from hil_sim.stereo import ir
from hil_sim.stereo.match import INVALID, correlated_noise, match
from hil_sim.stereo.params import StereoParams
from hil_sim.stereo.render import MultiViewRenderer, View, ViewImage
from hil_sim.world import CAMERA, World

PATTERN_SEED = 455
"""The projector's dot pattern is a property of the device: fixed, the same in every episode."""


@dataclass(frozen=True)
class StereoFrame:
    """One frame and its intermediates (working resolution), for pictures and calibration."""

    depth_mm: np.ndarray
    """uint16 at the 848x480 stream size, 0 = no data."""
    disparity: np.ndarray
    ir_left: np.ndarray
    ir_right: np.ndarray
    clean_z: np.ndarray
    """The left imager's exact z-depth, metres (inf where nothing is hit)."""


class Rig:
    """The sensor without a scene: imager and projector pinholes at the working resolution, the dot
    pattern, and the IR -> depth pipeline for views rendered elsewhere (a ``World``, or a synthetic plane)."""

    def __init__(self, params: StereoParams, stream: Intrinsics) -> None:
        self.params = p = params
        self.intr = _scaled(stream, p.render_scale)
        self.proj_intr = _scaled(stream, p.render_scale, focal_scale=1 / p.projector_fov_scale)
        spacing = p.dot_spacing_px / p.projector_fov_scale  # projector pixels are wider than the imager's
        self.pattern = ir.dot_pattern(self.proj_intr, spacing, p.dot_sigma_px / p.projector_fov_scale,
                                      PATTERN_SEED)
        self.views = [View(0.0, self.intr), View(p.baseline_m, self.intr),
                      View(p.projector_offset_m, self.proj_intr)]

    def frame(self, seen: list[ViewImage], materials: ir.Materials, rng: np.random.Generator) -> StereoFrame:
        """Depth from what the left imager, right imager and projector see (``seen``, in ``views`` order)."""
        p, intr = self.params, self.intr
        left, right, proj = seen
        projector = ir.Projector(p.projector_offset_m, self.proj_intr, self.pattern, proj)
        radiances = [ir.radiance(left, intr, 0.0, projector, materials, p),
                     ir.radiance(right, intr, p.baseline_m, projector, materials, p)]
        ir_left, ir_right = ir.expose(radiances, p, rng)
        disp = match(ir_left, ir_right, p)
        noisy = disp + correlated_noise(disp.shape, p.disparity_noise_px, p.noise_correlation_px, rng)
        valid = (disp != INVALID) & (noisy > 0)
        z = np.where(valid, intr.fx * p.baseline_m / np.where(valid, noisy, 1.0), 0.0)
        n = round(1 / p.render_scale)
        mm = to_millimetres(z, intr)
        return StereoFrame(np.repeat(np.repeat(mm, n, axis=0), n, axis=1), disp, ir_left, ir_right, left.z)

    def wall(self, z_m: float, seed: int, albedo: float | None = None) -> StereoFrame:
        """A frame of a flat wall (albedo default ``scene_albedo``) facing the sensor at ``z_m``."""
        seen = [ViewImage(np.full((v.intr.height, v.intr.width), z_m, np.float32),
                          np.zeros((v.intr.height, v.intr.width), np.int64)) for v in self.views]
        materials = ir.Materials.uniform(1, self.params.scene_albedo if albedo is None else albedo)
        return self.frame(seen, materials, np.random.default_rng(seed))


def episode_rng(seed: int) -> np.random.Generator:
    """Every random draw of episode ``seed``'s frames comes from this generator."""
    return np.random.default_rng([PATTERN_SEED, seed])


def draw_material(rng: np.random.Generator, params: StereoParams) -> str:
    """The object's IR material of an episode: the first draw from its generator."""
    return ir.MATERIAL_KINDS[int(rng.choice(len(ir.MATERIAL_KINDS), p=params.material_probs))]


def episode_material(seed: int, params: StereoParams) -> str:
    """The object's IR material in episode ``seed``, as ``StereoSensor.reset`` draws it, without a world."""
    return draw_material(episode_rng(seed), params)


class StereoSensor:
    """Scene sensor: ``reset(world, seed)`` at each episode start, then ``stream(world)`` per frame."""

    def __init__(self, params: StereoParams | None = None) -> None:
        self.params = params or StereoParams.load()
        self._renderer: MultiViewRenderer | None = None
        self._world: World | None = None
        self._rng = np.random.default_rng(0)
        self.material = "ordinary"

    def reset(self, world: World, seed: int) -> None:
        """Bind to ``world`` (first call builds the renderer) and draw this episode's IR materials."""
        if world is not self._world:
            self._bind(world)
        self._rng = episode_rng(seed)
        self.material = draw_material(self._rng, self.params)
        self._materials = self.materials_for(self.material)

    def materials_for(self, kind: str) -> ir.Materials:
        """Scene geoms at ``scene_albedo``, every object body's geoms of material ``kind``."""
        m = self._world.model
        mats = ir.Materials.uniform(m.ngeom, self.params.scene_albedo)
        for body in range(m.nbody):
            if m.body(body).name.startswith("obj_"):
                mats = mats.with_body(np.flatnonzero(m.geom_bodyid == body), kind, self._rng)
        return mats

    @property
    def materials(self) -> ir.Materials:
        """This episode's per-geom IR materials."""
        return self._materials

    def set_material(self, kind: str) -> None:
        """Force the object's IR material for the rest of the episode (tests, pictures)."""
        self._materials, self.material = self.materials_for(kind), kind

    def stream(self, world: World) -> np.ndarray:
        """uint16 mm depth at the stream resolution (0 = no data), as a D455 would give now."""
        return self.frame(world).depth_mm

    def frame(self, world: World) -> StereoFrame:
        return self.from_views(self.render(world))

    def render(self, world: World) -> list[ViewImage]:
        """What the left imager, right imager and projector see of ``world`` now."""
        if world is not self._world:
            raise RuntimeError("StereoSensor.reset(world, seed) must be called with this world first")
        return self._renderer.render(world.data, self.rig.views)

    def from_views(self, seen: list[ViewImage]) -> StereoFrame:
        return self.rig.frame(seen, self._materials, self._rng)

    def _bind(self, world: World) -> None:
        self.close()
        self.rig = Rig(self.params, world.intr)
        self._renderer = MultiViewRenderer(world.model, CAMERA, (self.rig.intr.width, self.rig.intr.height))
        self._world = world

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
        self._renderer, self._world = None, None


def _scaled(intr: Intrinsics, scale: float, focal_scale: float = 1.0) -> Intrinsics:
    """``intr`` at ``scale`` of its size (pixel centres kept), focal lengths times ``focal_scale``."""
    w, h = round(intr.width * scale), round(intr.height * scale)
    return Intrinsics(w, h, intr.fx * scale * focal_scale, intr.fy * scale * focal_scale,
                      (intr.cx + 0.5) * scale - 0.5, (intr.cy + 0.5) * scale - 0.5,
                      intr.min_z_m, intr.max_z_m)
