"""Infrared images of the active-stereo sensor: projector dot pattern, IR materials, image formation.

A view's pixel sees a 3-D point. The point carries the projector's dot pattern where the projector
reaches it (its ray is the first surface the projector sees), scaled by the Lambertian cosine to the
projector and the inverse square of the distance, plus ambient light, both times the geom's IR albedo
(modulated by a fixed passive texture of the surface, ``surface_texture``).
Shiny geoms add a narrow specular lobe of the projector (a glare without dots). One auto-exposure gain
for both imagers, read noise and 8-bit quantisation finish the images. Both imagers sample the same
pattern on the same surfaces, which is what makes the pair matchable; where the dots are dim (dark
material) or washed out (glare), it is not.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hil_sim.camera import Intrinsics
from hil_sim.stereo.params import StereoParams
from hil_sim.stereo.render import ViewImage

MATERIAL_KINDS = ("ordinary", "dark", "shiny")


@dataclass(frozen=True)
class Materials:
    """Per model geom: IR albedo, specular strength and specular exponent."""

    albedo: np.ndarray
    specular: np.ndarray
    shininess: np.ndarray

    @classmethod
    def uniform(cls, ngeom: int, albedo: float) -> Materials:
        return cls(np.full(ngeom + 1, albedo), np.zeros(ngeom + 1), np.ones(ngeom + 1))

    def lookup(self, geom: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-pixel values for a geom-id image; -1 (nothing hit) reads the extra last entry."""
        return self.albedo[geom], self.specular[geom], self.shininess[geom]

    def with_body(self, geoms: np.ndarray, kind: str, rng: np.random.Generator) -> Materials:
        """A copy with ``geoms`` given a randomly drawn material of ``kind``."""
        albedo, spec, shin = self.albedo.copy(), self.specular.copy(), self.shininess.copy()
        if kind == "ordinary":
            albedo[geoms] = rng.uniform(0.45, 0.9)
        elif kind == "dark":
            albedo[geoms] = rng.uniform(0.02, 0.08)
        elif kind == "shiny":
            albedo[geoms], spec[geoms], shin[geoms] = rng.uniform(0.04, 0.12), rng.uniform(2.0, 6.0), 60.0
        else:
            raise ValueError(f"unknown IR material {kind!r}; known: {', '.join(MATERIAL_KINDS)}")
        return Materials(albedo, spec, shin)


PATTERN_SUPERSAMPLING = 4
"""The pattern image has this many texels per projector pixel: dots are narrower than a pixel, and
sampling them from a pixel-sized grid would alias (measured: wall noise +40 %)."""


def dot_pattern(intr: Intrinsics, spacing_px: float, sigma_px: float, seed: int) -> np.ndarray:
    """The projector's fixed pseudo-random dots as a float32 image in [0, 1], ``PATTERN_SUPERSAMPLING``
    texels per pixel of ``intr``."""
    ss = PATTERN_SUPERSAMPLING
    h, w = intr.height * ss, intr.width * ss
    rng = np.random.default_rng(seed)
    # one dot per spacing x spacing cell at a random place in it: pseudo-random, yet no window is left
    # empty by chance as with uniformly scattered dots (a D4xx pattern is designed to be matchable)
    cy, cx = np.meshgrid(np.arange(0, intr.height, spacing_px), np.arange(0, intr.width, spacing_px),
                         indexing="ij")
    ys = ((cy + rng.uniform(0, spacing_px, cy.shape)) * ss).astype(int).clip(0, h - 1)
    xs = ((cx + rng.uniform(0, spacing_px, cx.shape)) * ss).astype(int).clip(0, w - 1)
    canvas = np.zeros((h, w), np.float32)
    canvas[ys, xs] = 1.0
    canvas = cv2.GaussianBlur(canvas, (0, 0), sigma_px * ss)
    return canvas / canvas.max()


def backproject(z: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """H x W x 3 points in the view's OpenCV frame (x right, y down, z forward)."""
    v, u = np.mgrid[0:intr.height, 0:intr.width].astype(np.float32)
    zf = np.where(np.isfinite(z), z, 0.0).astype(np.float32)
    return np.stack([(u - intr.cx) * zf / intr.fx, (v - intr.cy) * zf / intr.fy, zf], axis=-1)


def normals(points: np.ndarray) -> np.ndarray:
    """Unit surface normals from neighbouring points, turned towards the camera."""
    du = np.gradient(points, axis=1)
    dv = np.gradient(points, axis=0)
    n = np.cross(du, dv)
    n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-12
    return np.where(np.sum(n * points, axis=-1, keepdims=True) > 0, -n, n)


@dataclass(frozen=True)
class Projector:
    """The projector this frame: where it sits on the bar, its pinhole, its pattern and what it sees."""

    offset_m: float
    intr: Intrinsics
    pattern: np.ndarray
    seen: ViewImage


def radiance(view: ViewImage, intr: Intrinsics, view_offset_m: float, projector: Projector,
             materials: Materials, params: StereoParams) -> np.ndarray:
    """Light reaching each pixel of the imager at ``view_offset_m`` along the bar that sees ``view``, in
    units of a projector dot's peak on an albedo-1 surface facing it at 1 m (0 where nothing is hit)."""
    hit = np.isfinite(view.z)
    pts = backproject(view.z, intr)
    shift = np.array([projector.offset_m - view_offset_m, 0.0, 0.0], np.float32)
    to_proj = shift - pts
    dist2 = np.maximum(np.sum(to_proj**2, axis=-1), 1e-6)
    light = to_proj / np.sqrt(dist2)[..., None]
    n = normals(pts)
    cos = np.clip(np.sum(n * light, axis=-1), 0.0, 1.0)
    dots, lit = _projector_sample(pts - shift, projector, params.shadow_tolerance)
    albedo, spec, shin = materials.lookup(view.geom)
    if params.surface_texture > 0:
        bar_pts = pts + np.array([view_offset_m, 0.0, 0.0], np.float32)  # one frame for both imagers
        albedo = albedo * (1.0 + params.surface_texture * value_noise(bar_pts, params.texture_cell_m))
    irradiance = lit / dist2
    image = albedo * (params.ambient + irradiance * dots * cos)
    if np.any(spec > 0):
        view_dir = -pts / (np.linalg.norm(pts, axis=-1, keepdims=True) + 1e-12)
        mirror = 2 * cos[..., None] * n - light
        lobe = np.clip(np.sum(mirror * view_dir, axis=-1), 0.0, 1.0) ** shin
        image = image + spec * irradiance * lobe
    return np.where(hit, image, 0.0)


_LATTICE = np.random.default_rng(0).uniform(-1.0, 1.0, 1 << 16).astype(np.float32)
"""The texture's random values, looked up by a hash of the lattice cell (fixed: the same surface looks the
same in every frame and every run)."""


def value_noise(points: np.ndarray, cell_m: float) -> np.ndarray:
    """A fixed random value in [-1, 1] at every corner of a ``cell_m`` lattice, interpolated trilinearly at
    ``points`` [..., 3]: the same texture wherever the same surface point is seen from."""
    grid = np.nan_to_num(points / np.float32(cell_m), posinf=0.0, neginf=0.0)
    base = np.floor(grid)
    frac = (grid - base).astype(np.float32)
    cell = base.astype(np.int64)
    # Spatial hash into the table (primes as in Teschner et al. 2003): no visible period for matching to
    # confuse, unlike a wrapped small lattice.
    hx, hy, hz = cell[..., 0] * 73856093, cell[..., 1] * 19349663, cell[..., 2] * 83492791
    mask = len(_LATTICE) - 1
    fx, fy, fz = frac[..., 0], frac[..., 1], frac[..., 2]
    out = np.zeros(points.shape[:-1], np.float32)
    for dx, wx in ((0, 1 - fx), (73856093, fx)):
        for dy, wy in ((0, 1 - fy), (19349663, fy)):
            for dz, wz in ((0, 1 - fz), (83492791, fz)):
                out += wx * wy * wz * _LATTICE[((hx + dx) ^ (hy + dy) ^ (hz + dz)) & mask]
    return out


def expose(radiances: list[np.ndarray], params: StereoParams, rng: np.random.Generator) -> list[np.ndarray]:
    """8-bit images of both imagers under one auto-exposure gain (the left image's lit median goes to
    ``exposure_level``), with read noise."""
    lit = radiances[0][radiances[0] > 0]
    gain = params.exposure_level / max(float(np.median(lit)), 1e-9) if lit.size else 0.0
    return [np.clip(np.rint(gain * r + rng.normal(0.0, params.read_noise, r.shape)), 0, 255).astype(np.uint8)
            for r in radiances]


def _projector_sample(pts_proj: np.ndarray, projector: Projector, tolerance: float,
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Pattern value at each point (given in the projector's frame) and whether the projector reaches it,
    i.e. no nearer surface shadows it."""
    intr = projector.intr
    z = np.maximum(pts_proj[..., 2], 1e-6)
    u = (intr.fx * pts_proj[..., 0] / z + intr.cx).astype(np.float32)
    v = (intr.fy * pts_proj[..., 1] / z + intr.cy).astype(np.float32)
    ss = PATTERN_SUPERSAMPLING  # texel centre of pixel u: ss * (u + 0.5) - 0.5
    dots = cv2.remap(projector.pattern, ss * u + (ss - 1) / 2, ss * v + (ss - 1) / 2, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT)
    seen_z = np.where(np.isfinite(projector.seen.z), projector.seen.z, 1e6).astype(np.float32)
    first = cv2.remap(seen_z, u, v, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    lit = (pts_proj[..., 2] > 0) & (pts_proj[..., 2] <= first * (1.0 + tolerance))
    return dots, lit.astype(np.float32)
