"""The 12 graspable object kinds (paper: 6 seen, 6 unseen) and user objects loaded from a file.

Every kind is procedural: a few MuJoCo primitives or a generated mesh with a plausible size, mass and
friction, sized to fit the Panda's 8 cm gripper. Each object becomes one free body named ``obj_<name>``
whose geoms are named ``obj_<name>_g<i>``; ``World`` parks the bodies that are not in play.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path


class ObjectError(ValueError):
    """An object kind that does not exist or whose asset cannot be used."""


class UnknownObjectError(ObjectError):
    """A name that is neither a built-in kind nor a path to a user object."""


class MissingAssetError(ObjectError, FileNotFoundError):
    """A user object path that does not exist or has an unsupported format."""


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
    mesh_file: str = ""
    """Path of a user mesh (.stl/.obj) referenced by ``Geom.mesh``."""
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
    ObjectKind("lemon", 9, (Geom("ellipsoid", (0.034, 0.026, 0.026)),), 0.10, 0.9, (1.0, 0.9, 0.1, 1),
               seen=False),
    ObjectKind("can", 10, (Geom("cylinder", (0.033, 0.06)),), 0.30, 0.7, (0.7, 0.7, 0.75, 1), seen=False),
    ObjectKind("wheel", 11, (Geom("cylinder", (0.03, 0.012)), Geom("cylinder", (0.012, 0.018))), 0.08, 1.0,
               (0.15, 0.15, 0.15, 1), seen=False),
    ObjectKind("bread", 12, (Geom("box", (0.05, 0.033, 0.022)),
                             Geom("capsule", (0.022,), fromto=(-0.05, 0, 0.014, 0.05, 0, 0.014))),
               0.10, 0.8, (0.8, 0.6, 0.35, 1), seen=False),
)
KINDS: dict[str, ObjectKind] = {k.name: k for k in BUILTIN}
SEEN: tuple[str, ...] = tuple(k.name for k in BUILTIN if k.seen)
UNSEEN: tuple[str, ...] = tuple(k.name for k in BUILTIN if not k.seen)
GROUPS: dict[str, tuple[str, ...]] = {"seen": SEEN, "unseen": UNSEEN, "all": SEEN + UNSEEN}
_MESH_SUFFIXES = (".stl", ".obj")


def resolve(name_or_path: str, category_id: int = 13) -> ObjectKind:
    """A built-in kind by name, or a user object from a mesh (.stl/.obj) or MJCF (.xml) path."""
    if name_or_path in KINDS:
        return KINDS[name_or_path]
    looks_like_path = any(c in name_or_path for c in "/\\.")
    if not looks_like_path:
        raise UnknownObjectError(f"unknown object kind {name_or_path!r}; built-in kinds: {', '.join(KINDS)} "
                                 f"(or give a path to an .stl/.obj mesh or an MJCF .xml)")
    path = Path(name_or_path).expanduser()
    if not path.is_file():
        raise MissingAssetError(f"object asset {str(path)!r} does not exist")
    if path.suffix.lower() in _MESH_SUFFIXES:
        return _mesh_object(path, category_id)
    if path.suffix.lower() == ".xml":
        return _mjcf_object(path, category_id)
    raise MissingAssetError(f"object asset {str(path)!r} has unsupported format {path.suffix!r} "
                            f"(use .stl, .obj or an MJCF .xml)")


def _safe_name(path: Path) -> str:
    return "".join(c if c.isalnum() else "_" for c in path.stem).lower() or "user"


def _mesh_object(path: Path, category_id: int) -> ObjectKind:
    """A user mesh: 0.15 kg, friction 0.9, collided as its convex hull (MuJoCo's rule for meshes)."""
    name = _safe_name(path)
    return ObjectKind(name, category_id, (Geom("mesh", mesh=name),), 0.15, 0.9, (0.6, 0.5, 0.7, 1),
                      mesh_file=str(path.resolve()), seen=False)


def _mjcf_object(path: Path, category_id: int) -> ObjectKind:
    """A user MJCF: the geoms of its first worldbody body (primitives only) become the object."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise MissingAssetError(f"object MJCF {str(path)!r} is not valid XML: {exc}") from None
    body = root.find("./worldbody/body")
    geoms = body.findall("geom") if body is not None else []
    if not geoms:
        raise MissingAssetError(f"object MJCF {str(path)!r} has no <worldbody><body> with <geom>s")
    parsed = []
    for g in geoms:
        gtype = g.get("type", "sphere")
        if gtype == "mesh":
            raise MissingAssetError(f"object MJCF {str(path)!r}: mesh geoms are not supported, "
                                    f"pass the mesh file itself")
        parsed.append(Geom(gtype, _floats(g.get("size", "0.03")), _floats(g.get("pos", "0 0 0")),
                           _floats(g.get("euler", "0 0 0"))))
    mass = 0.15
    return ObjectKind(_safe_name(path), category_id, tuple(parsed), mass, 0.9, (0.6, 0.5, 0.7, 1), seen=False)


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split())


def _join(values: tuple[float, ...]) -> str:
    return " ".join(map(str, values))


def body_xml(kind: ObjectKind) -> str:
    """The free body MJCF of one object; the mass is split evenly over its geoms."""
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
    """The <asset> entry for a generated or user mesh ('' when the kind has none)."""
    if kind.mesh_vertices:
        return f'<mesh name="{kind.name}" vertex="{" ".join(map(str, kind.mesh_vertices))}"/>'
    if kind.mesh_file:
        return f'<mesh name="{kind.name}" file="{kind.mesh_file}"/>'
    return ""
