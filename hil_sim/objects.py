"""The 12 graspable object kinds (paper: 6 seen, 6 unseen) and user objects loaded from a file.

Every built-in kind is procedural: a few MuJoCo primitives or a generated mesh with a plausible size, mass
and friction, sized to fit the Panda's 8 cm gripper. Each becomes one free body named ``obj_<name>`` whose
geoms are named ``obj_<name>_g<i>``; ``World`` parks the bodies that are not in play.

A user object is an MJCF file or a mesh that MuJoCo itself loads (``mujoco.MjSpec``), so its geoms, nested
bodies, defaults, masses, frictions and mesh assets are what MuJoCo makes of them. The world checks only
what it needs (one rigid top body, a narrow side the gripper spans, a pose it rests in) and puts that body
inside a free body ``obj_<name>`` centred on its bounding box, axes as in the file: the world, the reward
and the expert read an object's position as its centre and its z axis as up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import mujoco
import numpy as np


class ObjectError(ValueError):
    """An object kind that does not exist or whose asset cannot be used."""


class UnknownObjectError(ObjectError):
    """A name that is neither a built-in kind nor a path to a user object."""


class MissingAssetError(ObjectError, FileNotFoundError):
    """A user object path that does not exist or has an unsupported format."""


class InvalidObjectError(ObjectError):
    """A user object file that MuJoCo refuses, or that the world cannot place and grasp."""


@dataclass(frozen=True)
class Geom:
    """One primitive (MuJoCo geom type and size) or mesh, placed in the object's frame."""

    type: str
    size: tuple[float, ...] = ()
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mesh: str = ""
    fromto: tuple[float, ...] = ()
    """Capsule end points (x1 y1 z1 x2 y2 z2); replaces pos/euler when given."""


@dataclass(frozen=True)
class ObjectKind:
    name: str
    category_id: int
    """1..12 for built-ins (the privileged observation carries log(category_id))."""
    geoms: tuple[Geom, ...]
    mass: float
    """kg, spread over the geoms by volume."""
    friction: float
    rgba: tuple[float, float, float, float] = (0.8, 0.3, 0.2, 1.0)
    mesh_vertices: tuple[float, ...] = ()
    """Flat xyz list for a generated mesh referenced by ``Geom.mesh``."""
    seen: bool = True

    @property
    def body_name(self) -> str:
        return f"obj_{self.name}"


def _star_prism(points: int = 5, r_out: float = 0.032, r_in: float = 0.018, half_len: float = 0.05) -> tuple:
    """Starfruit: a five-pointed star cross-section extruded along x (MuJoCo collides its convex hull)."""
    verts = []
    for x in (-half_len, half_len):
        for i in range(2 * points):
            r = r_out if i % 2 == 0 else r_in
            a = math.pi * i / points
            verts += [x, r * math.cos(a), r * math.sin(a)]
    return tuple(round(v, 5) for v in verts)


def _banana_geoms(radius: float = 0.17, sweep: float = 0.9, thickness: float = 0.018) -> tuple[Geom, ...]:
    """Three capsules along an arc (about 19 cm long, 3.6 cm thick) lying flat, centred on the bend."""
    angles = [sweep * (i / 3 - 0.5) for i in range(4)]
    pts = [(radius * math.sin(a), radius * (1 - math.cos(a)) - 0.012) for a in angles]
    return tuple(Geom("capsule", (thickness,), fromto=tuple(round(v, 4) for v in (*p, 0.0, *q, 0.0)))
                 for p, q in zip(pts, pts[1:], strict=False))


BUILTIN: tuple[ObjectKind, ...] = (
    ObjectKind("apple", 1, (Geom("ellipsoid", (0.036, 0.036, 0.033)),), 0.18, 1.0, (0.75, 0.1, 0.1, 1)),
    ObjectKind("pear", 2, (Geom("sphere", (0.033,), (0, 0, -0.012)), Geom("sphere", (0.022,), (0, 0, 0.025))),
               0.17, 0.9, (0.7, 0.8, 0.2, 1)),
    ObjectKind("peach", 3, (Geom("sphere", (0.032,)),), 0.15, 1.0, (1.0, 0.6, 0.4, 1)),
    ObjectKind("banana", 4, _banana_geoms(), 0.12, 0.9, (0.95, 0.85, 0.2, 1)),
    ObjectKind("cube", 5, (Geom("box", (0.025, 0.025, 0.025)),), 0.10, 0.8, (0.2, 0.4, 0.8, 1)),
    ObjectKind("block", 6, (Geom("box", (0.05, 0.025, 0.025)),), 0.15, 0.8, (0.3, 0.7, 0.3, 1)),
    ObjectKind("persimmon", 7, (Geom("ellipsoid", (0.034, 0.034, 0.026)),), 0.17, 1.0, (0.95, 0.45, 0.1, 1),
               seen=False),
    ObjectKind("starfruit", 8, (Geom("mesh", mesh="starfruit"),), 0.12, 0.9, (0.85, 0.8, 0.2, 1),
               mesh_vertices=_star_prism(), seen=False),
    ObjectKind("lemon", 9, (Geom("ellipsoid", (0.034, 0.027, 0.025)),), 0.10, 0.9, (1.0, 0.9, 0.1, 1),
               seen=False),
    ObjectKind("can", 10, (Geom("cylinder", (0.033, 0.06)),), 0.30, 0.7, (0.7, 0.7, 0.75, 1), seen=False),
    ObjectKind("wheel", 11, (Geom("cylinder", (0.03, 0.012)), Geom("cylinder", (0.012, 0.018))), 0.08, 1.0,
               (0.15, 0.15, 0.15, 1), seen=False),
    ObjectKind("bread", 12, (Geom("box", (0.05, 0.033, 0.022)),
                             Geom("capsule", (0.022,), fromto=(-0.05, 0, 0.014, 0.05, 0, 0.014))),
               0.10, 0.8, (0.8, 0.6, 0.35, 1), seen=False),
)
SHAPE_COUNT, SHAPE_SEED = 24, 0
"""How many procedural training shapes there are (group ``shapes``) and the seed that draws them."""
MIN_HALF = 0.02
"""A shape's smallest half extent, across or up (4 cm). Twelve more shapes 3-4 cm tall (boxes and lying
capsules, which the expert lifts 240 of 240 times) gained the readout nothing on wheels (history.md)."""
SHAPE_DENSITY = 600.0
"""kg/m^3 of a procedural shape (a fruit's is 500-1000), its mass then held to the built-ins' 0.05-0.35 kg."""


def _shape(i: int, rng: np.random.Generator) -> ObjectKind:
    """Training shape ``shape<i>``: a box, a flattened ellipsoid or a lying capsule of random proportions.

    Only the primitive types of the seen kinds are drawn: no upright cylinder and no mesh, so the unseen can,
    wheel and starfruit stay of a type no training shape has. Every shape is stable as it lies (an ellipsoid's
    height below its horizontal semi-axes; a box no taller than twice its narrow side) and spans 4-7.2 cm
    across its narrow side (the apple 7.2)."""
    narrow = rng.uniform(MIN_HALF, 0.036)
    kind = ("box", "ellipsoid", "capsule")[i % 3]
    if kind == "box":
        size = (narrow, rng.uniform(narrow, 0.07), rng.uniform(MIN_HALF, min(0.065, 2 * narrow)))
        geom, volume = Geom("box", size), 8 * math.prod(size)
    elif kind == "ellipsoid":
        size = (narrow, rng.uniform(narrow, 0.06), max(MIN_HALF, rng.uniform(0.5, 0.95) * narrow))
        geom, volume = Geom("ellipsoid", size), 4 / 3 * math.pi * math.prod(size)
    else:
        half = rng.uniform(0.0, 0.05)  # the straight part's half length along x
        geom = Geom("capsule", (narrow,), fromto=(-half, 0.0, 0.0, half, 0.0, 0.0))
        volume = math.pi * narrow ** 2 * (2 * half + 4 / 3 * narrow)
    return _training_kind(f"shape{i:02d}", geom, volume, rng)


def _square(i: int, rng: np.random.Generator) -> ObjectKind:
    """Training box ``square<i>``: square in plan view (sides within 4 %, so round to the labels and the
    expert: any closing direction), flat-topped, 4.4-5.2 cm across and 10-13 cm tall, as the can (12) and
    taller than any shape. No training kind was over 10.4 cm tall, the tall ones all elongated, and the
    readout read a round object 12 cm tall (the can, a cylinder of its size) as elongated even after square
    boxes up to 8.7 cm tall had taught it round ones up to 9.5 cm (docs/history.md, 2026-11-30). Across the
    diagonal, the widest grasp, one is at most 7.35 cm (the gripper opens 8)."""
    half = rng.uniform(0.022, 0.026)
    size = (half, half * rng.uniform(1.0, 1.04), rng.uniform(0.05, 0.065))
    return _training_kind(f"square{i:02d}", Geom("box", size), 8 * math.prod(size), rng)


def _scaled(kind: ObjectKind, scale: float) -> ObjectKind:
    """A seen kind made ``scale`` times as large (category 13, as user objects; mass with the volume)."""
    def times(values: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(round(v * scale, 4) for v in values)

    geoms = tuple(Geom(g.type, times(g.size), times(g.pos), g.euler, g.mesh, times(g.fromto))
                  for g in kind.geoms)
    mass = round(float(np.clip(kind.mass * scale ** 3, 0.05, 0.35)), 3)
    return ObjectKind(f"{kind.name}_x{round(scale * 100)}", 13, geoms, mass, kind.friction, kind.rgba)


def _training_kind(name: str, geom: Geom, volume: float, rng: np.random.Generator) -> ObjectKind:
    """A one-geom training kind (category 13, as user objects) weighed at ``SHAPE_DENSITY``, of random colour
    and friction."""
    mass = float(np.clip(SHAPE_DENSITY * volume, 0.05, 0.35))
    rgba = (*np.round(rng.uniform(0.15, 0.95, 3), 2), 1.0)
    friction = round(float(rng.uniform(0.7, 1.0)), 2)  # drawn after the colour, as the kinds were first drawn
    return ObjectKind(name, 13, (_rounded(geom),), round(mass, 3), friction, rgba)


def _rounded(geom: Geom) -> Geom:
    return Geom(geom.type, tuple(round(float(v), 4) for v in geom.size), mesh=geom.mesh,
                fromto=tuple(round(float(v), 4) for v in geom.fromto))


_SHAPE_RNG = np.random.default_rng(SHAPE_SEED)
SHAPES: tuple[ObjectKind, ...] = tuple(_shape(i, _SHAPE_RNG) for i in range(SHAPE_COUNT))
"""Procedural shapes for training only (category 13, as user objects): the seen kinds' primitives at random
proportions and sizes, which a student needs to read and grasp shapes it was not shown. Evaluation keeps
the 12 built-in kinds."""
SQUARE_COUNT, SQUARE_SEED = 8, 1
_SQUARE_RNG = np.random.default_rng(SQUARE_SEED)
SQUARES: tuple[ObjectKind, ...] = tuple(_square(i, _SQUARE_RNG) for i in range(SQUARE_COUNT))
"""Square training boxes (group ``squares``), apart from ``SHAPES`` so that ``train`` stays what the
lineages before them were trained on."""
SUPERQUADRIC_COUNT, SUPERQUADRIC_SEED = 24, 5


def _superquadric_vertices(half: tuple[float, float, float], e_up: float, e_around: float,
                           rings: int = 13, around: int = 24) -> tuple[float, ...]:
    """Surface points of a superquadric of half extents ``half``: ``e_up`` shapes its side view (0.2
    flat-topped as a cylinder, 1 round as an ellipsoid), ``e_around`` its plan (0.2 square, 1 elliptic)."""
    up, turn = np.meshgrid(np.linspace(-np.pi / 2, np.pi / 2, rings),
                           np.linspace(-np.pi, np.pi, around, endpoint=False))
    ring = _signed_power(np.cos(up), e_up)
    pts = np.stack([half[0] * ring * _signed_power(np.cos(turn), e_around),
                    half[1] * ring * _signed_power(np.sin(turn), e_around),
                    half[2] * _signed_power(np.sin(up), e_up)], axis=-1).reshape(-1, 3)
    return tuple(round(float(v), 5) for v in np.unique(pts.round(5), axis=0).ravel())


def _signed_power(t: np.ndarray, e: float) -> np.ndarray:
    return np.sign(t) * np.abs(t) ** e


def _superquadric_volume(half: tuple[float, float, float], e_up: float, e_around: float) -> float:
    """Jaklic, Leonardis and Solina, Segmentation and Recovery of Superquadrics (2000), eq. 2.60."""
    def beta(x: float, y: float) -> float:
        return math.gamma(x) * math.gamma(y) / math.gamma(x + y)

    return 2 * math.prod(half) * e_up * e_around * beta(e_up / 2 + 1, e_up) * beta(e_around / 2, e_around / 2)


def _superquadric(i: int, rng: np.random.Generator) -> ObjectKind:
    """Training kind ``superquadric<i>``: one convex superquadric mesh between a box, a cylinder and an
    ellipsoid, 4-7.2 cm across its narrow side (y) and up to 13 cm tall: a continuous family of forms and
    sizes, so that the readout must measure an object rather than recall one of the few it was shown. Only a
    flat-bottomed one (``e_up`` < 0.4) may be taller than it is narrow: a rounder one would rock."""
    narrow = rng.uniform(MIN_HALF, 0.036)
    e_up, e_around = rng.uniform(0.2, 1.0), rng.uniform(0.2, 1.0)
    tallest = 2 * narrow if e_up < 0.4 else 0.95 * narrow
    half = (rng.uniform(narrow, 0.06), narrow, rng.uniform(MIN_HALF, min(0.065, tallest)))
    name = f"superquadric{i:02d}"
    kind = _training_kind(name, Geom("mesh", mesh=name), _superquadric_volume(half, e_up, e_around), rng)
    return replace(kind, mesh_vertices=_superquadric_vertices(half, e_up, e_around))


_SUPERQUADRIC_RNG = np.random.default_rng(SUPERQUADRIC_SEED)
SUPERQUADRICS: tuple[ObjectKind, ...] = tuple(_superquadric(i, _SUPERQUADRIC_RNG)
                                              for i in range(SUPERQUADRIC_COUNT))
"""Superquadric training kinds (group ``superquadrics``): forms between and beyond the training shapes',
upright round ones among them, at sizes drawn anew for each kind."""
_NARROW_CM = {"apple": 7.2, "pear": 6.6, "peach": 6.4, "banana": 3.6, "cube": 5.0, "block": 5.0}
_SCALE_RNG = np.random.default_rng(SQUARE_SEED + 3)
SCALED: tuple[ObjectKind, ...] = tuple(
    _scaled(k, round(float(_SCALE_RNG.uniform(*span)), 2)) for k in BUILTIN if k.seen
    for span in ((0.75, 0.9), (1.1, min(1.3, 7.4 / _NARROW_CM[k.name]))) if span[0] < span[1])
"""The seen kinds smaller and larger (group ``scaled``): known shapes at sizes the readout must read, not
recall (``_NARROW_CM``: each kind's narrow side, so that a larger copy still fits the 8 cm stroke)."""
KINDS: dict[str, ObjectKind] = {k.name: k for k in BUILTIN + SHAPES + SQUARES + SCALED + SUPERQUADRICS}
SEEN: tuple[str, ...] = tuple(k.name for k in BUILTIN if k.seen)
UNSEEN: tuple[str, ...] = tuple(k.name for k in BUILTIN if not k.seen)
GROUPS: dict[str, tuple[str, ...]] = {"seen": SEEN, "unseen": UNSEEN, "all": SEEN + UNSEEN,
                                      "shapes": tuple(k.name for k in SHAPES),
                                      "train": SEEN + tuple(k.name for k in SHAPES),
                                      "squares": tuple(k.name for k in SQUARES),
                                      "scaled": tuple(k.name for k in SCALED),
                                      "superquadrics": tuple(k.name for k in SUPERQUADRICS)}
OBJECTS_HELP = f"kinds, object files and groups ({', '.join(GROUPS)}), comma-separated"
"""The ``--objects`` help of every command (each resolves it with ``select_kinds``)."""
_MESH_SUFFIXES = (".stl", ".obj")
MESH_DENSITY = 1000.0
"""kg/m^3 of a bare mesh object: MuJoCo's default geom density (about a fruit's, so a 6 cm cube weighs
216 g). For another mass or friction, write an MJCF with the mesh beside it."""
MAX_WIDTH_M = 0.078
"""Widest narrow side: the gripper opens 8 cm; a millimetre is left on either side."""
REST_S, REST_SPEED = 2.0, (0.01, 0.2)
"""Dropped onto a flat table in its file's pose, an object must move slower than (m/s, rad/s) after that
time: it may settle or fall over first, but it must come to rest."""
_TABLE_FRICTION = (0.8, 0.005, 0.0001)
"""The world's table (``hil_sim.world._scene_xml``): the rest check drops objects on the same surface."""


@dataclass(frozen=True)
class UserObject:
    """An object from a user's file, checked and measured by ``resolve``; ``add_to`` loads it into a spec."""

    name: str
    category_id: int
    path: Path
    offset: tuple[float, float, float]
    """Where the file's world origin lies in the free body's frame: minus the bounding box's centre."""
    turn: tuple[float, float, float, float]
    """The free body's frame from the file's world frame (w, x, y, z): a turn about z only."""
    seen: bool = False

    @property
    def body_name(self) -> str:
        return f"obj_{self.name}"

    def add_to(self, spec: mujoco.MjSpec, pos: tuple[float, float, float] = (0.0, 0.0, -1.0)) -> None:
        """Attach the file's body to ``spec`` inside the free body ``body_name`` placed at ``pos``."""
        _attach(spec, self.path, self.body_name, pos, self.offset, self.turn)


AnyObject = ObjectKind | UserObject


def resolve(name_or_path: str, category_id: int = 13) -> AnyObject:
    """A built-in kind by name, or a user object from a mesh (.stl/.obj) or MJCF (.xml) path."""
    if name_or_path in KINDS:
        return KINDS[name_or_path]
    looks_like_path = any(c in name_or_path for c in "/\\.")
    if not looks_like_path:
        raise UnknownObjectError(f"unknown object kind {name_or_path!r}; built-in kinds: "
                                 f"{', '.join(GROUPS['all'])}, shape00..shape{SHAPE_COUNT - 1:02d} and "
                                 f"square00..square{SQUARE_COUNT - 1:02d} "
                                 f"(or give a path to an .stl/.obj mesh or an MJCF .xml)")
    path = Path(name_or_path).expanduser().resolve()
    if not path.is_file():
        raise MissingAssetError(f"object asset {name_or_path!r} does not exist")
    if path.suffix.lower() not in (*_MESH_SUFFIXES, ".xml"):
        raise MissingAssetError(f"object asset {name_or_path!r} has unsupported format {path.suffix!r} "
                                f"(use .stl, .obj or an MJCF .xml)")
    return _measure(path, category_id)


def select_kinds(spec: str) -> tuple[str, ...]:
    """Kinds named by ``spec`` (a comma list of groups and kinds), each checked to exist before any work
    starts."""
    kinds = tuple(kind for s in spec.split(",") if s for kind in GROUPS.get(s, (s,)))
    if not kinds:
        raise ObjectError(f"no object kinds in {spec!r}")
    for kind in kinds:
        resolve(kind)
    return kinds


def _measure(path: Path, category_id: int) -> UserObject:
    """Load the object alone on a table, measure its bounds and check that the world can use it."""
    name = "".join(c if c.isalnum() else "_" for c in path.name).lower()  # a.xml and a.obj differ
    spec = mujoco.MjSpec()
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.1], friction=_TABLE_FRICTION)
    _attach(spec, path, "object", (0.0, 0.0, 0.0))
    model = _compile(spec, path)
    body = model.body("object").id
    geoms = colliding_geoms(model, body)
    if not geoms.size:
        raise InvalidObjectError(f"object {str(path)!r} has no geom that collides (contype or conaffinity)")
    points = geom_corners(model, body, geoms)
    _check_rests(model, float(points[:, 2].min()), path)
    yaw = _narrowest_yaw(points)
    turn = np.array([np.cos(yaw / 2), 0.0, 0.0, -np.sin(yaw / 2)])
    points = _turned(points, turn)
    lo, hi = points.min(axis=0), points.max(axis=0)
    width = float(min(hi[:2] - lo[:2]))
    if width > MAX_WIDTH_M:
        raise InvalidObjectError(f"object {str(path)!r} is {width * 100:.1f} cm across its narrower "
                                 f"horizontal side; the gripper spans {MAX_WIDTH_M * 100:.1f} cm "
                                 f"(lengths are in metres)")
    return UserObject(name, category_id, path, _floats(-(lo + hi) / 2), _floats(turn))


def _turned(points: np.ndarray, quat: np.ndarray) -> np.ndarray:
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, quat)
    return points @ rot.reshape(3, 3).T


def _narrowest_yaw(points: np.ndarray) -> float:
    """The direction in the horizontal plane (0 to 180 deg in half degrees; the first of equals) across which
    the points are narrowest. Made the object's x axis, its x and y are its narrow and long sides whatever yaw
    the file drew it at: the expert grasps across the narrower one, the width the gripper must span."""
    yaws = np.radians(np.arange(0.0, 180.0, 0.5))
    widths = np.ptp(points[:, :2] @ np.stack([np.cos(yaws), np.sin(yaws)]), axis=0)
    return float(yaws[np.argmin(np.round(widths, 6))])


def _check_rests(model: mujoco.MjModel, bottom: float, path: Path) -> None:
    """Drop the object (its free joint the model's only joint) 2 mm onto the table in its file's pose, as
    ``World`` places it; refuse one still rolling or rocking after ``REST_S``: the expert plans from the
    object's pose as it lies. (Unstable balance passes, as the built-in pear's: nothing nudges it.)"""
    data = mujoco.MjData(model)
    data.qpos[2] = 0.002 - bottom
    mujoco.mj_step(model, data, nstep=round(REST_S / model.opt.timestep))
    speed = np.linalg.norm(data.qvel[:3]), np.linalg.norm(data.qvel[3:6])
    if not (speed[0] < REST_SPEED[0] and speed[1] < REST_SPEED[1]):
        raise InvalidObjectError(f"object {str(path)!r} does not come to rest on a table in its file's pose "
                                 f"(after {REST_S:g} s it moves at {speed[0] * 100:.1f} cm/s, "
                                 f"{speed[1]:.2f} rad/s); pose it lying on a side")


def _attach(spec: mujoco.MjSpec, path: Path, body_name: str, pos: tuple[float, ...],
            offset: tuple[float, ...] = (0.0, 0.0, 0.0), turn: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0)
            ) -> None:
    """The file's top body, welded inside a new free body ``body_name`` at ``pos`` through a frame
    (``offset``, ``turn``) that puts its bounding box's centre at the free body's origin."""
    user = _load(path)
    top = _top_body(user, path)
    free = spec.worldbody.add_body(name=body_name, pos=list(pos))
    free.add_freejoint(name=f"{body_name}_free")
    free.add_frame(pos=list(offset), quat=list(turn)).attach_body(top, f"{body_name}/", "")


def _load(path: Path) -> mujoco.MjSpec:
    if path.suffix.lower() in _MESH_SUFFIXES:
        return _mesh_spec(path)
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise InvalidObjectError(f"object {str(path)!r}: {_first_line(exc)}") from None


def _mesh_spec(path: Path) -> mujoco.MjSpec:
    """A bare mesh as the one-geom MJCF body MuJoCo would make of it, weighed at ``MESH_DENSITY``."""
    spec = mujoco.MjSpec()
    spec.add_mesh(name="mesh", file=str(path))
    body = spec.worldbody.add_body(name="mesh")
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="mesh", density=MESH_DENSITY)
    return spec


def _top_body(spec: mujoco.MjSpec, path: Path) -> mujoco.MjsBody:
    """The file's one top body, its free joint removed (the world gives it one): refuse a file with none or
    several, or with any other joint, since an object must move as one rigid body."""
    tops = list(spec.worldbody.bodies)
    if len(tops) != 1:
        found = ", ".join(repr(b.name) for b in tops) or "none"
        raise InvalidObjectError(f"object {str(path)!r} must hold one top body (the object) in <worldbody>; "
                                 f"found {found}")
    for joint in list(spec.joints):
        if joint.type != mujoco.mjtJoint.mjJNT_FREE or joint.parent != tops[0]:
            raise InvalidObjectError(f"object {str(path)!r}: joint {joint.name!r} in body "
                                     f"{joint.parent.name!r}; an object is one rigid body (nested bodies "
                                     f"welded, at most a free joint on the top one)")
        spec.delete(joint)
    return tops[0]


def _compile(spec: mujoco.MjSpec, path: Path) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as exc:
        raise InvalidObjectError(f"object {str(path)!r}: {_first_line(exc)}") from None


def colliding_geoms(m: mujoco.MjModel, root: int) -> np.ndarray:
    """Geoms that collide (visual-only ones excluded) in the bodies under the top-level body ``root``."""
    geoms = np.flatnonzero(m.body_rootid[m.geom_bodyid] == root)
    return geoms[(m.geom_contype[geoms] | m.geom_conaffinity[geoms]) != 0]


def local_bounds(m: mujoco.MjModel, root: int, geoms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds of the geoms' boxes in the frame of their ancestor body ``root`` (exact for
    primitives whose axes are that frame's, conservative for turned ones)."""
    pts = geom_corners(m, root, geoms)
    return pts.min(axis=0), pts.max(axis=0)


def geom_corners(m: mujoco.MjModel, root: int, geoms: np.ndarray) -> np.ndarray:
    """The 8 corners of each geom's bounding box (its own axes) in ``root``'s frame, (8 * len(geoms), 3)."""
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    corners = []
    for g in geoms:
        pos, quat = _pose_in(m, root, g)
        centre, half = m.geom_aabb[g, :3], m.geom_aabb[g, 3:]
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, quat)
        corners.append((centre + signs * half) @ rot.reshape(3, 3).T + pos)
    return np.concatenate(corners)


def _pose_in(m: mujoco.MjModel, root: int, geom: int) -> tuple[np.ndarray, np.ndarray]:
    """Position and quaternion of ``geom`` in ``root``'s frame, through the bodies between them as compiled.
    A geom of ``root`` itself keeps its compiled numbers untouched (built-in kinds' bounds stay exact)."""
    pos, quat = m.geom_pos[geom], m.geom_quat[geom]
    body = m.geom_bodyid[geom]
    while body != root:
        outer_pos, outer_quat = np.zeros(3), np.zeros(4)
        mujoco.mju_mulPose(outer_pos, outer_quat, m.body_pos[body], m.body_quat[body], pos, quat)
        pos, quat, body = outer_pos, outer_quat, m.body_parentid[body]
    return pos, quat


def _first_line(exc: Exception) -> str:
    return str(exc).strip().splitlines()[0]


def _floats(values: np.ndarray) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def _join(values: tuple[float, ...]) -> str:
    return " ".join(map(str, values))


def body_xml(kind: ObjectKind) -> str:
    """The free body MJCF of one built-in kind; the mass is split evenly over its geoms."""
    rgba = " ".join(map(str, kind.rgba))
    geoms = []
    for i, g in enumerate(kind.geoms):
        shape = f'mesh="{g.mesh}"' if g.type == "mesh" else f'size="{_join(g.size)}"'
        place = (f'fromto="{_join(g.fromto)}"' if g.fromto
                 else f'pos="{_join(g.pos)}" euler="{_join(g.euler)}"')
        geoms.append(f'<geom name="{kind.body_name}_g{i}" type="{g.type}" {shape} {place} '
                     f'mass="{kind.mass / len(kind.geoms):.5f}" friction="{kind.friction} 0.01 0.0001" '
                     f'condim="4" rgba="{rgba}" group="1"/>')
    return (f'<body name="{kind.body_name}" pos="0 0 -1"><freejoint name="{kind.body_name}_free"/>'
            + "".join(geoms) + "</body>")


def mesh_xml(kind: ObjectKind) -> str:
    """The <asset> entry of a built-in kind's generated mesh ('' when it has none)."""
    if kind.mesh_vertices:
        return f'<mesh name="{kind.name}" vertex="{" ".join(map(str, kind.mesh_vertices))}"/>'
    return ""
