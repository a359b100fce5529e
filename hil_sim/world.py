"""The MuJoCo grasping world shared by the trainer's gym env and hil_sim's real-time server (no torch).

Scene: the Franka Panda of the ``gymnasium-robotics`` wheel (position actuators, parallel gripper, loaded
by path from the installed package) bolted on a 75 cm table, a floor, a statically mounted D455
(``hil_sim.camera``) and every object kind in play as its own free body. Objects not in the current
episode are parked under the floor with collisions and gravity off, so one compiled model (and one
renderer) serves all kinds. The arm links are gravity compensated, as the real Franka's controller is.

World frame: z up, floor at z=0, table top at ``TABLE_Z``, robot base at (0, 0, TABLE_Z) facing +x.
Objects start at random in a 40 cm (y) x 30 cm (x) workspace centred 50 cm in front of the base.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import mujoco
import numpy as np

from hil_sim import objects
from hil_sim.camera import DepthCamera, Intrinsics, d455_intrinsics, extrinsics, look_at_quat
from runtime.preprocess import DepthSpec, policy_state

TABLE_Z = 0.75
WORKSPACE_X = (0.35, 0.65)
WORKSPACE_Y = (-0.20, 0.20)
CAMERA_POS = (1.30, 0.20, TABLE_Z + 0.60)
CAMERA_TARGET = (0.50, 0.0, TABLE_Z + 0.18)
HOME_Q = (0.0, -0.30, 0.0, -2.20, 0.0, 0.35, 0.0)
"""Ready pose: hand about 40 cm above the table centre, pointing down (found with the expert's IK). In this
model's angles, as every joint angle in hil_sim; libfranka's add ``kinematics.HIL_SIM_Q_OFFSET``."""
GRIPPER_OPEN_M = 0.04
"""Per-finger travel; the gripper opening (state[7]) is the sum of both fingers, 0..0.08 m."""
FINGER_KP = 1500.0
"""Finger servo gain, N/m: ~45 N on a 6 cm object, inside the Franka Hand's 70 N continuous force."""
ARM_JOINTS = tuple(f"robot:panda0_joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("robot:panda0_finger_joint1", "robot:panda0_finger_joint2")
FINGER_BODIES = ("panda0_leftfinger", "panda0_rightfinger")
EE_SITE = "end_effector"
CAMERA = "d455"
POLICY_CAMERA = "d455_policy"
"""The same camera seeing only the episode's crop window at the policy resolution (8x cheaper to render)."""
SETTLE_S = 0.3
_PARK_Z = -0.5


class WorldError(RuntimeError):
    """The world cannot be built or driven as asked (bad command shape, missing robot assets)."""


def franka_assets_dir() -> Path:
    """``kitchen_franka/franka_assets`` inside the installed gymnasium-robotics wheel."""
    import importlib.util

    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or spec.origin is None:
        raise WorldError("gymnasium-robotics is not installed; it ships the Panda model (pip install "
                         "gymnasium-robotics==1.4.2)")
    path = Path(spec.origin).parent / "envs" / "assets" / "kitchen_franka" / "franka_assets"
    if not (path / "chain.xml").is_file():
        raise WorldError(f"Panda MJCF not found at {path}")
    return path


@dataclass(frozen=True)
class Randomisation:
    """Ranges of the per-episode domain randomisation (paper III-C: dynamics, initial joints, camera,
    crop window)."""

    link_mass_scale: tuple[float, float] = (0.85, 1.15)
    """Multiplier on each arm link's mass and inertia."""
    joint_friction: tuple[float, float] = (0.0, 0.3)
    """Coulomb friction (frictionloss) of each arm joint, N m."""
    joint_damping_scale: tuple[float, float] = (0.8, 1.2)
    """Multiplier on each arm joint's damping."""
    joint_stiffness: tuple[float, float] = (0.0, 2.0)
    """Passive spring of each arm joint towards the home pose, N m / rad."""
    init_joint_noise: float = 0.05
    """Uniform +- noise on the home joint angles, rad."""
    wrist_noise: float = 0.05
    """Uniform +- noise on the wrist's (joint 7) home angle, rad. Demos may widen it (``trainer collect
    --wrist-noise``): with the wrist always starting near home, its angle alone tells a student which way the
    expert has been turning it, and the student learns that instead of reading the object's yaw."""
    camera_pos_noise: float = 0.02
    """Uniform +- offset of the camera position per axis, m."""
    camera_rot_noise_deg: float = 2.0
    """Uniform +- rotation of the camera about each of its axes, degrees."""
    crop_shift: tuple[int, int] = (30, 40)
    """Max +- shift (rows, cols) of the depth crop window from the centred one, pixels."""


@dataclass(frozen=True)
class Episode:
    """Everything drawn at reset; stored per episode in datasets (``asdict`` is JSON-ready)."""

    kind: str
    seed: int
    randomised: bool
    object_xy: tuple[float, float]
    object_yaw: float
    q0: tuple[float, ...]
    crop_window: tuple[int, int]
    camera_pos: tuple[float, float, float]
    camera_quat: tuple[float, float, float, float]
    link_mass_scale: tuple[float, ...] = ()
    joint_friction: tuple[float, ...] = ()
    joint_damping_scale: tuple[float, ...] = ()
    joint_stiffness: tuple[float, ...] = ()

    def to_dict(self) -> dict:
        return asdict(self)


class World:
    """One Panda, one table, one D455 and the given object kinds (built-in names or user file paths)."""

    def __init__(self, kinds: Sequence[str] = objects.GROUPS["all"], *, spec: DepthSpec | None = None,
                 timestep: float = 0.002, randomisation: Randomisation | None = None) -> None:
        self.spec = spec or DepthSpec()
        self.intr: Intrinsics = d455_intrinsics(self.spec)
        self.randomisation = randomisation or Randomisation()
        resolved = [objects.resolve(k, category_id=13 + i) for i, k in enumerate(kinds)]
        self.kinds: dict[str, objects.AnyObject] = dict(zip(kinds, resolved, strict=True))
        top, left = self.spec.centred_window()
        self.model = _compile(list(self.kinds.values()), self.intr, self.intr.window(top, left, self.spec),
                              timestep)
        self.data = mujoco.MjData(self.model)
        self._ids = _Ids(self.model, self.kinds)
        self._nominal = _Nominal.of(self.model)
        self.camera = DepthCamera(self.model, CAMERA, self.intr)
        self.policy_camera = DepthCamera(self.model, POLICY_CAMERA, self.intr.window(top, left, self.spec))
        self.episode: Episode | None = None
        self.kind: objects.AnyObject | None = None

    # --- episode ------------------------------------------------------------------------------------
    def reset(self, kind: str, seed: int, *, randomise: bool = True) -> Episode:
        """Start an episode with ``kind`` placed at random; dynamics/camera/crop randomised when asked."""
        if kind not in self.kinds:
            raise objects.UnknownObjectError(f"object kind {kind!r} is not in this world "
                                             f"(have: {', '.join(self.kinds)})")
        rng = np.random.default_rng(seed)
        self._nominal.restore(self.model)
        mujoco.mj_resetData(self.model, self.data)
        xy = (rng.uniform(*WORKSPACE_X), rng.uniform(*WORKSPACE_Y))
        yaw = rng.uniform(-np.pi, np.pi)
        episode = (self._draw(rng, kind, seed, xy, yaw) if randomise
                   else self._nominal_episode(kind, seed, xy, yaw))
        self._apply(episode)
        self.episode, self.kind = episode, self.kinds[kind]
        self._settle()
        return episode

    def _draw(self, rng: np.random.Generator, kind: str, seed: int, xy, yaw) -> Episode:
        r, n = self.randomisation, len(ARM_JOINTS)
        cam_pos = np.asarray(CAMERA_POS) + rng.uniform(-r.camera_pos_noise, r.camera_pos_noise, 3)
        quat = look_at_quat(cam_pos, np.asarray(CAMERA_TARGET))
        tilt, max_tilt = np.zeros(4), r.camera_rot_noise_deg
        mujoco.mju_euler2Quat(tilt, np.deg2rad(rng.uniform(-max_tilt, max_tilt, 3)), "xyz")
        mujoco.mju_mulQuat(quat, quat.copy(), tilt)
        top, left = self.spec.centred_window()
        top += int(rng.integers(-r.crop_shift[0], r.crop_shift[0] + 1))
        left += int(rng.integers(-r.crop_shift[1], r.crop_shift[1] + 1))
        top = int(np.clip(top, 0, self.spec.stream_height - self.spec.crop_height))
        left = int(np.clip(left, 0, self.spec.stream_width - self.spec.crop_width))
        # One draw for every joint, scaled as numpy's uniform(-a, a) scales it: default episodes unchanged.
        half = np.r_[np.full(n - 1, r.init_joint_noise), r.wrist_noise]
        noise = -half + 2 * half * rng.random(n)
        q0 = np.asarray(HOME_Q) + noise
        return Episode(kind, seed, True, _round(xy), float(yaw), _round(q0), (top, left), _round(cam_pos),
                       _round(quat),
                       link_mass_scale=_round(rng.uniform(*r.link_mass_scale, len(self._ids.links))),
                       joint_friction=_round(rng.uniform(*r.joint_friction, n)),
                       joint_damping_scale=_round(rng.uniform(*r.joint_damping_scale, n)),
                       joint_stiffness=_round(rng.uniform(*r.joint_stiffness, n)))

    def _nominal_episode(self, kind: str, seed: int, xy, yaw) -> Episode:
        quat = look_at_quat(np.asarray(CAMERA_POS), np.asarray(CAMERA_TARGET))
        return Episode(kind, seed, False, _round(xy), float(yaw), HOME_Q, self.spec.centred_window(),
                       CAMERA_POS, _round(quat))

    def _apply(self, ep: Episode) -> None:
        m, d, ids = self.model, self.data, self._ids
        for scale, body in zip(ep.link_mass_scale, ids.links, strict=False):
            m.body_mass[body] *= scale
            m.body_inertia[body] *= scale
        if ep.randomised:
            m.dof_frictionloss[ids.arm_dofs] = ep.joint_friction
            m.jnt_stiffness[ids.arm_joints] = ep.joint_stiffness
            m.dof_damping[ids.arm_dofs] *= ep.joint_damping_scale
        m.qpos_spring[ids.arm_qpos] = HOME_Q
        m.cam_pos[[ids.camera, ids.policy_camera]] = ep.camera_pos
        m.cam_quat[[ids.camera, ids.policy_camera]] = ep.camera_quat
        m.cam_intrinsic[ids.policy_camera] = self.intr.window(*ep.crop_window, self.spec).mj_intrinsic()
        d.qpos[ids.arm_qpos] = ep.q0
        d.qpos[ids.finger_qpos] = GRIPPER_OPEN_M
        self.set_targets(np.asarray(ep.q0), -1.0)
        for i, name in enumerate(self.kinds):
            self._place(name, ep if name == ep.kind else None, i)
        mujoco.mj_forward(m, d)

    def _place(self, name: str, ep: Episode | None, index: int) -> None:
        """Put the episode's object on the table; park the others under the floor, inert."""
        m, d, obj = self.model, self.data, self._ids.objects[name]
        active = ep is not None
        if not active:  # an active object keeps the contacts it was compiled with (restored at reset)
            m.geom_contype[obj.geoms] = m.geom_conaffinity[obj.geoms] = 0
        m.body_gravcomp[obj.bodies] = 0.0 if active else 1.0
        if active:
            pos = (*ep.object_xy, TABLE_Z + obj.bottom_offset + 0.002)
            quat = (np.cos(ep.object_yaw / 2), 0.0, 0.0, np.sin(ep.object_yaw / 2))
        else:
            pos, quat = (-1.0 - 0.3 * index, 2.0, _PARK_Z), (1.0, 0.0, 0.0, 0.0)
        d.qpos[obj.qpos:obj.qpos + 7] = (*pos, *quat)
        d.qvel[obj.dof:obj.dof + 6] = 0.0

    def _settle(self) -> None:
        self.step(SETTLE_S)
        self.data.time = 0.0

    # --- control ------------------------------------------------------------------------------------
    def set_targets(self, q: np.ndarray, gripper: float) -> None:
        """Arm position targets (7 rad, clipped to the actuator range) and gripper -1 open / +1 close."""
        q = np.asarray(q, dtype=float)
        if q.shape != (7,) or not np.all(np.isfinite(q)):
            raise WorldError(f"joint targets must be 7 finite numbers, got shape {q.shape}")
        if not np.isfinite(gripper):
            raise WorldError(f"gripper command must be finite, got {gripper}")
        lo, hi = self.model.actuator_ctrlrange[:7].T
        self.data.ctrl[:7] = np.clip(q, lo, hi)
        self.data.ctrl[7:9] = 0.0 if gripper > 0 else GRIPPER_OPEN_M

    def step(self, dt: float) -> None:
        """Advance physics by ``dt`` seconds (rounded to whole timesteps, at least one)."""
        mujoco.mj_step(self.model, self.data, nstep=max(1, round(dt / self.model.opt.timestep)))

    def snapshot(self) -> mujoco.MjData:
        """A copy of the simulation state, derived quantities included, to ``restore`` after running ahead
        (e.g. to label a state with an expert's next actions): the world is then exactly as it was."""
        return copy.copy(self.data)

    def restore(self, snapshot: mujoco.MjData) -> None:
        mujoco.mj_copyData(self.data, self.model, snapshot)

    # --- readings -----------------------------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        return self.data.qpos[self._ids.arm_qpos].copy()

    @property
    def dq(self) -> np.ndarray:
        return self.data.qvel[self._ids.arm_dofs].copy()

    def finger_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Both finger slides: positions (2, m) and velocities (2, m/s)."""
        return self.data.qpos[self._ids.finger_qpos].copy(), self.data.qvel[self._ids.finger_dofs].copy()

    @property
    def gripper_opening(self) -> float:
        return float(self.data.qpos[self._ids.finger_qpos].sum())

    def joint_state(self) -> np.ndarray:
        """The 8-d state the student sees (``runtime.preprocess.policy_state``): this model's joint angles."""
        return policy_state(self.q, self.gripper_opening)

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Grasp site between the finger pads: position (3) and quaternion (w, x, y, z)."""
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, self.data.site_xmat[self._ids.ee_site])
        return self.data.site_xpos[self._ids.ee_site].copy(), quat

    def ee_xmat(self) -> np.ndarray:
        return self.data.site_xmat[self._ids.ee_site].reshape(3, 3).copy()

    def finger_positions(self) -> np.ndarray:
        """World positions (2 x 3) of the left and right finger bodies."""
        return self.data.xpos[list(self._ids.fingers)].copy()

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Position (3) and quaternion (w, x, y, z) of the current object."""
        obj = self._active()
        return self.data.xpos[obj.body].copy(), self.data.xquat[obj.body].copy()

    def object_extent(self) -> np.ndarray:
        """Half extents (x, y, z) of the current object's bounding box in its own frame, m."""
        return self._active().half_extent.copy()

    def finger_contacts(self) -> tuple[bool, bool]:
        """Whether the left / right finger touches the current object."""
        obj, fingers = self._active(), self._ids.fingers
        touching = [False, False]
        for c in self.data.contact[: self.data.ncon]:
            bodies = {int(self.model.geom_bodyid[c.geom1]), int(self.model.geom_bodyid[c.geom2])}
            if not bodies.isdisjoint(obj.bodies):
                for i, f in enumerate(fingers):
                    touching[i] |= f in bodies
        return touching[0], touching[1]

    def _active(self) -> _Object:
        if self.episode is None:
            raise WorldError("call reset() before reading the object")
        return self._ids.objects[self.episode.kind]

    # --- camera -------------------------------------------------------------------------------------
    def render_depth(self) -> np.ndarray:
        """uint16 mm depth frame at the stream resolution (0 = no data)."""
        return self.camera.depth_mm(self.data)

    def render_policy_depth(self) -> np.ndarray:
        """uint16 mm depth of the episode's crop window rendered directly at the policy resolution: what
        ``crop_resize(render_depth(), spec, window)`` gives, up to sub-pixel sampling at depth edges."""
        return self.policy_camera.depth_mm(self.data)

    def render_rgb(self) -> np.ndarray:
        return self.camera.rgb(self.data)

    def render_policy_rgb(self) -> np.ndarray:
        """uint8 RGB of the crop window at the policy resolution (as ``render_policy_depth``)."""
        return self.policy_camera.rgb(self.data)

    def aim_camera(self, pos: np.ndarray, target: np.ndarray) -> None:
        """Move the full-stream camera to ``pos`` looking at ``target`` (world frame, z up) until the next
        ``reset``: views of the scene other than the robot's mount (the DDG metrics' matched views)."""
        cam = self._ids.camera
        self.model.cam_pos[cam] = pos
        self.model.cam_quat[cam] = look_at_quat(np.asarray(pos, float), np.asarray(target, float))
        mujoco.mj_forward(self.model, self.data)

    def camera_extrinsics(self) -> np.ndarray:
        """4x4 world-from-camera transform, OpenCV axes."""
        cam = self._ids.camera
        return extrinsics(self.data.cam_xpos[cam], self.data.cam_xmat[cam])

    def close(self) -> None:
        self.camera.close()
        self.policy_camera.close()


@dataclass(frozen=True)
class _Object:
    body: int
    """The free body; a user object's own bodies hang under it."""
    bodies: np.ndarray
    geoms: np.ndarray
    """The colliding geoms of all its bodies."""
    qpos: int
    dof: int
    bottom_offset: float
    half_extent: np.ndarray


class _Ids:
    """Model indices looked up once."""

    def __init__(self, m: mujoco.MjModel, kinds: dict[str, objects.AnyObject]) -> None:
        self.arm_joints = jid = np.array([m.joint(n).id for n in ARM_JOINTS])
        self.arm_qpos = m.jnt_qposadr[jid]
        self.arm_dofs = m.jnt_dofadr[jid]
        fid = [m.joint(n).id for n in FINGER_JOINTS]
        self.finger_qpos, self.finger_dofs = m.jnt_qposadr[fid], m.jnt_dofadr[fid]
        self.fingers = tuple(m.body(n).id for n in FINGER_BODIES)
        self.links = [m.body(f"panda0_link{i}").id for i in range(1, 8)]
        self.ee_site = m.site(EE_SITE).id
        self.camera = m.camera(CAMERA).id
        self.policy_camera = m.camera(POLICY_CAMERA).id
        self.objects = {name: _object_ids(m, kind) for name, kind in kinds.items()}


def _object_ids(m: mujoco.MjModel, kind: objects.AnyObject) -> _Object:
    body = m.body(kind.body_name).id
    geoms = objects.colliding_geoms(m, body)
    joint = m.body_jntadr[body]
    lo, hi = objects.local_bounds(m, body, geoms)
    return _Object(body, np.flatnonzero(m.body_rootid == body), geoms, int(m.jnt_qposadr[joint]),
                   int(m.jnt_dofadr[joint]), float(-lo[2]), (hi - lo) / 2)


@dataclass
class _Nominal:
    """Model fields the randomisation touches, as compiled, so every reset starts from them."""

    fields: dict[str, np.ndarray]

    NAMES = ("body_mass", "body_inertia", "dof_frictionloss", "dof_damping", "jnt_stiffness", "cam_pos",
             "cam_quat", "cam_intrinsic", "geom_contype", "geom_conaffinity", "body_gravcomp", "qpos_spring")

    @classmethod
    def of(cls, m: mujoco.MjModel) -> _Nominal:
        return cls({n: getattr(m, n).copy() for n in cls.NAMES})

    def restore(self, m: mujoco.MjModel) -> None:
        for name, value in self.fields.items():
            getattr(m, name)[:] = value


def _round(values, digits: int = 6) -> tuple:
    return tuple(round(float(v), digits) for v in np.ravel(values))


def _compile(kinds: list[objects.AnyObject], intr: Intrinsics, policy_intr: Intrinsics,
             timestep: float) -> mujoco.MjModel:
    """Built-in kinds are written into the scene's MJCF; user objects are attached from their own files after
    it, so a world of built-in kinds alone compiles exactly as it always has."""
    xml = _scene_xml([k for k in kinds if isinstance(k, objects.ObjectKind)], intr, policy_intr, timestep)
    try:
        spec = mujoco.MjSpec.from_string(xml, _franka_includes())
        for kind in kinds:
            if isinstance(kind, objects.UserObject):
                kind.add_to(spec)
        _absolute_meshes(spec)
        for body in spec.bodies:
            if body.name.startswith("panda0_"):
                body.gravcomp = 1.0
        for actuator in spec.actuators:
            if "gripper" in actuator.name:  # the wheel's kp 500 squeezes a 6 cm object with ~16 N
                actuator.gainprm[0], actuator.biasprm[1] = FINGER_KP, -FINGER_KP
        return spec.compile()
    except objects.ObjectError:  # a user object's own error already names its file
        raise
    except ValueError as exc:
        raise objects.MissingAssetError(f"cannot build the world: {str(exc).splitlines()[0]}") from None


def _absolute_meshes(spec: mujoco.MjSpec) -> None:
    """Point the wheel's meshes at the installed files (its meshdir is relative to the wheel's own xml)."""
    meshes = franka_assets_dir() / "meshes"
    for mesh in spec.meshes:
        if mesh.file.startswith("franka_assets/"):
            mesh.file = str(meshes / mesh.file.removeprefix("franka_assets/"))


def _franka_includes() -> dict[str, bytes]:
    """The wheel's Panda MJCF files, keyed as the scene includes them."""
    return {f"franka_assets/{p.name}": p.read_bytes() for p in franka_assets_dir().glob("*.xml")}


def _scene_xml(kinds: list[objects.ObjectKind], intr: Intrinsics, policy_intr: Intrinsics,
               timestep: float) -> str:
    quat = " ".join(f"{v:.6f}" for v in look_at_quat(np.asarray(CAMERA_POS), np.asarray(CAMERA_TARGET)))
    meshes = "".join(objects.mesh_xml(k) for k in kinds)
    bodies = "".join(objects.body_xml(k) for k in kinds)
    return f"""<mujoco model="diffudepgrasp">
  <include file="franka_assets/assets.xml"/>
  <option timestep="{timestep}" integrator="implicitfast"/>
  <visual><global offwidth="{intr.width}" offheight="{intr.height}"/><map znear="0.02" zfar="10"/></visual>
  <statistic extent="1" center="0.5 0 {TABLE_Z}"/>
  <asset>{meshes}</asset>
  <worldbody>
    <light pos="0.5 0 3" dir="0 0 -1" diffuse="0.8 0.8 0.8"/>
    <geom name="floor" type="plane" size="4 4 0.1" rgba="0.45 0.45 0.45 1"/>
    <geom name="table" type="box" pos="0.45 0 {TABLE_Z / 2}" size="0.55 0.6 {TABLE_Z / 2}"
          rgba="0.6 0.5 0.4 1" friction="0.8 0.005 0.0001"/>
    <body name="robot_base" pos="0 0 {TABLE_Z}"><include file="franka_assets/chain.xml"/></body>
    <camera name="{CAMERA}" pos="{" ".join(map(str, CAMERA_POS))}" quat="{quat}" {intr.mjcf_attributes()}/>
    <camera name="{POLICY_CAMERA}" pos="{" ".join(map(str, CAMERA_POS))}" quat="{quat}"
            {policy_intr.mjcf_attributes()}/>
    {bodies}
  </worldbody>
  <include file="franka_assets/actuator.xml"/>
</mujoco>"""
