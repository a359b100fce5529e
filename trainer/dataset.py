"""Demo store (zarr v3): what ``collect`` writes and the student / DDG stages read.

Layout (names are a contract):
    data/depth   uint16  [N, 96, 128]  policy resolution, mm, 0 = no data (after crop_resize, episode window)
    data/state   float32 [N, 8]        7 joint angles (rad) + gripper opening (m)
    data/action  float32 [N, 8]        env action: 7 deltas in [-1, 1] before the scale s, gripper -1/+1
    data/rgb     uint8   [N, 96, 128, 3]  optional, same crop and resize as depth
    data/depth_sensor  uint16 [N, 96, 128]  optional: what the sensor ``attrs["sensor"]`` (e.g. stereo)
                       showed the policy at that step, as the policy sees it (``collect --sensor``); under
                       a generated source's sensor (e.g. ``residual_edges:steps=5``) that source's frames
    data/labels  float32 [N, 12]       optional: the frame's privileged perception labels (trainer.sim.labels)
    data/chunk   float32 [N, Hc, 8]    optional, with labels: the expert's next Hc actions from the step's
                       state (its label of a state a learner reached: ``trainer.student.dagger``); Hc = attrs
                       ``chunk_horizon``. ``data/action`` is then what was executed.
    data/depth_ddg, data/depth_ddg_nograft  uint16 [N, 96, 128]  optional: DDG depth of each frame, with
                       and without the simulated geometry grafted back (``trainer.ddg.generate``), made chunk
                       by chunk
    data/depth_residual  uint16 [N, 96, 128]  optional: the residual diffusion's depth of each frame
                       (``trainer.ddg.generate --generator residual``), made chunk by chunk
    meta/ddg_done, meta/residual_done  bool [N / chunk]  with a generator's depth: which of its chunks are
                       made (its settings: attrs ``ddg`` or ``residual``)
    meta/episode_ends       int64   [E]     cumulative end index of each stored (successful) episode
    meta/kind               str     [E]     object kind
    meta/seed               int64   [E]
    meta/crop_window        int32   [E, 2]  (top, left) in the 848x480 stream
    meta/camera_K           float64 [E, 3, 3]
    meta/camera_extrinsics  float64 [E, 4, 4]  world-from-camera, OpenCV axes
    meta/randomisation      str     [E]     JSON of the episode's draws (hil_sim.world.Episode)
    attrs: depth_spec, action_scale, control_rate_hz, depth_scale (0.001), attempted, succeeded, failed,
           teacher, seed, sensor (with data/depth_sensor), chunk_horizon (with data/chunk),
           ddg, residual (with a generator's depth: its model, steps, seed, chunk and eta)
Each depth a student can train on (``DEPTH_SOURCES``) is one of these arrays; ``DemoStore.depth`` reads it
and refuses one the store lacks or has not finished generating.
Episodes are appended whole: data arrays first, then the per-episode meta, then ``episode_ends`` last, so
an interrupted write is cut back to the last complete episode on the next open.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zarr
from zarr.codecs import BloscCodec

from runtime.preprocess import DepthSpec
from trainer.sim.labels import LABELS

DEPTH_SCALE = 0.001
_CHUNK_STEPS = 512
_META = {"kind": (str, ()), "seed": (np.int64, ()), "crop_window": (np.int32, (2,)),
         "camera_K": (np.float64, (3, 3)), "camera_extrinsics": (np.float64, (4, 4)),
         "randomisation": (str, ())}


@dataclass(frozen=True)
class DepthSource:
    """Where a depth source's frames are stored, and the command that adds them to a store without them."""

    array: str
    made_by: str = ""
    """Empty: every store holds the array."""
    labelled_by: str = ""
    """The command that makes a labelled store (a DAgger round's) with the array, where it is another."""


DEPTH_SOURCES = {
    "gt": DepthSource("data/depth"),
    "randnoise": DepthSource("data/depth"),  # procedural noise on the clean frames, at sampling time
    "ddg": DepthSource("data/depth_ddg", "python -m trainer ddg generate"),
    "ddg_nograft": DepthSource("data/depth_ddg_nograft", "python -m trainer ddg generate"),
    "sensor": DepthSource("data/depth_sensor", "python -m trainer collect --sensor",
                          "python -m trainer student readout --store S --episodes N --sensor"),
    "residual": DepthSource("data/depth_residual", "python -m trainer ddg generate --generator residual"),
    "residual_edges": DepthSource("data/depth_residual_edges",
                                  "python -m trainer ddg generate --generator residual_edges"),
}
"""Depth source -> its stored array. sensor: what a simulated sensor showed at each step."""
GENERATORS = {"ddg": ("ddg", "ddg_nograft"), "residual": ("residual",), "residual_edges": ("residual_edges",)}
"""Each generator -> the sources it makes chunk by chunk (``DemoStore.generation_outputs``); its settings are
the store's attrs[generator], its record of made chunks ``meta/<generator>_done``."""


def generator_of(source: str) -> str | None:
    """The generator that makes depth ``source``; None for one stored as collected."""
    return next((g for g, made in GENERATORS.items() if source in made), None)


def _done(generator: str) -> str:
    return f"meta/{generator}_done"


class DatasetError(OSError):
    """A demo store that cannot be created, opened or appended to, or lacks the depth asked of it."""


@dataclass(frozen=True)
class EpisodeRecord:
    """One successful episode ready to append (arrays stacked over its steps)."""

    depth: np.ndarray
    state: np.ndarray
    action: np.ndarray
    kind: str
    seed: int
    crop_window: tuple[int, int]
    camera_K: np.ndarray
    camera_extrinsics: np.ndarray
    randomisation: dict
    rgb: np.ndarray | None = None
    depth_sensor: np.ndarray | None = None
    labels: np.ndarray | None = None
    chunk: np.ndarray | None = None


def sizes(spec: DepthSpec) -> str:
    """How a message names a depth spec: its resolution and crop."""
    return f"{spec.out_width}x{spec.out_height} depth of a {spec.crop_width}x{spec.crop_height} crop"


class DemoStore:
    """Append-only episode store; ``DemoStore.open(path)`` to read, ``DemoStore.create`` to write."""

    def __init__(self, root: zarr.Group, path: str | Path = "") -> None:
        self.root = root
        self.path = str(path)
        """How messages name the store."""

    # --- opening ------------------------------------------------------------------------------------
    @classmethod
    def open(cls, path: str | Path, mode: str = "r") -> DemoStore:
        path = Path(path)
        if not (path / "zarr.json").is_file():
            raise DatasetError(f"no demo store at {str(path)!r}")
        try:
            store = cls(zarr.open_group(str(path), mode=mode), path)
            store.root["meta/episode_ends"]
        except (KeyError, ValueError, OSError) as exc:
            raise DatasetError(f"{str(path)!r} is not a demo store: {exc}") from None
        if mode != "r":
            store._truncate_partial()
        return store

    @classmethod
    def create(cls, path: str | Path, *, spec: DepthSpec, action_scale: float, control_rate_hz: float,
               rgb: bool = False, sensor: str | None = None, labels: bool = False, chunk_horizon: int = 0,
               attrs: dict | None = None) -> DemoStore:
        """A new empty store, or the existing one at ``path`` reopened for appending (resume). ``sensor``: the
        store keeps that sensor's frames too (``data/depth_sensor``); a store to resume must keep the same.
        ``labels``: it keeps each frame's perception labels; ``chunk_horizon`` > 0 (with labels): the expert's
        action chunks of that length too."""
        if chunk_horizon and not labels:
            raise DatasetError("a store of expert chunks keeps the frames' labels too: labels=True")
        path = Path(path)
        if (path / "zarr.json").is_file():
            store = cls.open(path, mode="a")
            if store.attrs.get("sensor") != sensor:
                raise DatasetError(f"{str(path)!r} keeps the frames of sensor {store.attrs.get('sensor')!r}, "
                                   f"not {sensor!r}: resume it with the same sensor, or choose another store")
            if ("data/labels" in store.root) != labels:
                held = "keeps" if not labels else "keeps no"
                raise DatasetError(f"{str(path)!r} {held} perception labels, unlike the episodes to add: "
                                   "choose another store")
            kept = store.attrs.get("chunk_horizon", 0)
            if kept != chunk_horizon:
                raise DatasetError(f"{str(path)!r} keeps expert chunks of {kept} steps, not {chunk_horizon}: "
                                   "choose another store")
            if store.depth_spec != spec:
                raise DatasetError(f"{str(path)!r} keeps {sizes(store.depth_spec)}, not {sizes(spec)}: "
                                   "resume it with the same resolution, or choose another store")
            return store
        # Built beside its final name and renamed into place, so neither a reader nor a resume ever sees a
        # store without its arrays (a kill during creation leaves only the ".creating" folder).
        staging = path.with_name(path.name + ".creating")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            root = zarr.open_group(str(staging), mode="w")
        except OSError as exc:
            raise DatasetError(f"cannot write a demo store at {str(path)!r}: {exc.strerror or exc}") from None
        h, w = spec.out_height, spec.out_width
        arrays = {"data/depth": ((h, w), np.uint16), "data/state": ((8,), np.float32),
                  "data/action": ((8,), np.float32)}
        if rgb:
            arrays["data/rgb"] = ((h, w, 3), np.uint8)
        if sensor is not None:
            arrays["data/depth_sensor"] = ((h, w), np.uint16)
        if labels:
            arrays["data/labels"] = ((len(LABELS),), np.float32)
        if chunk_horizon:
            arrays["data/chunk"] = ((chunk_horizon, 8), np.float32)
        for name, (shape, dtype) in arrays.items():
            root.create_array(name, shape=(0, *shape), chunks=(_CHUNK_STEPS, *shape), dtype=dtype,
                              compressors=BloscCodec(cname="zstd", clevel=5, shuffle="bitshuffle"))
        root.create_array("meta/episode_ends", shape=(0,), chunks=(4096,), dtype=np.int64)
        for name, (dtype, shape) in _META.items():
            root.create_array(f"meta/{name}", shape=(0, *shape), chunks=(4096, *shape), dtype=dtype)
        root.attrs.update({"depth_spec": spec.to_dict(), "action_scale": action_scale,
                           "control_rate_hz": control_rate_hz, "depth_scale": DEPTH_SCALE,
                           "attempted": 0, "succeeded": 0, "failed": 0, **(attrs or {}),
                           **({"sensor": sensor} if sensor is not None else {}),
                           **({"chunk_horizon": chunk_horizon} if chunk_horizon else {})})
        try:
            staging.rename(path)
        except OSError as exc:
            raise DatasetError(f"cannot write a demo store at {str(path)!r}: {exc.strerror or exc}") from None
        return cls(zarr.open_group(str(path), mode="a"), path)

    def _truncate_partial(self) -> None:
        """Cut arrays back to the last complete episode (a write interrupted half way)."""
        n_ep = len(self.episode_ends)
        n = int(self.episode_ends[-1]) if n_ep else 0
        for arr in self._data_arrays().values():
            if arr.shape[0] != n:
                arr.resize((n, *arr.shape[1:]))
        for name in _META:
            arr = self.root[f"meta/{name}"]
            if arr.shape[0] != n_ep:
                arr.resize((n_ep, *arr.shape[1:]))

    # --- writing ------------------------------------------------------------------------------------
    def append(self, ep: EpisodeRecord) -> None:
        steps = len(ep.action)
        arrays = {"depth": ep.depth, "state": ep.state, "action": ep.action}
        for name, what in (("rgb", "RGB"), ("depth_sensor", "sensor frames"), ("labels", "labels"),
                           ("chunk", "expert chunks")):
            if name in self._data_arrays():
                if getattr(ep, name) is None:
                    raise DatasetError(f"this store keeps {what} but the episode has none")
                arrays[name] = getattr(ep, name)
        for name, value in arrays.items():
            if len(value) != steps:
                raise DatasetError(f"episode {name} has {len(value)} steps, action has {steps}")
            self.root[f"data/{name}"].append(np.asarray(value), axis=0)
        meta = {"kind": np.array([ep.kind]), "seed": [ep.seed], "crop_window": [ep.crop_window],
                "camera_K": [ep.camera_K], "camera_extrinsics": [ep.camera_extrinsics],
                "randomisation": np.array([json.dumps(ep.randomisation)])}
        for name, value in meta.items():
            dtype = _META[name][0]
            self.root[f"meta/{name}"].append(value if dtype is str else np.asarray(value, dtype), axis=0)
        ends = self.root["meta/episode_ends"]
        end = (int(ends[-1]) if ends.shape[0] else 0) + steps
        ends.append(np.array([end], np.int64))

    def count(self, *, success: bool) -> None:
        """Record one attempt in the store's counters (a DAgger round keeps its failed episodes too)."""
        a = self.root.attrs
        a.update({"attempted": int(a["attempted"]) + 1, "succeeded": int(a["succeeded"]) + success,
                  "failed": int(a["failed"]) + (not success)})

    # --- reading ------------------------------------------------------------------------------------
    @property
    def episode_ends(self) -> np.ndarray:
        return self.root["meta/episode_ends"][:]

    @property
    def episode_lengths(self) -> np.ndarray:
        """Steps per episode."""
        return np.diff(self.episode_ends, prepend=0)

    @property
    def kinds(self) -> list[str]:
        """Each episode's object kind."""
        return [str(k) for k in self.root["meta/kind"][:]]

    @property
    def n_episodes(self) -> int:
        return int(self.root["meta/episode_ends"].shape[0])

    @property
    def n_steps(self) -> int:
        ends = self.episode_ends
        return int(ends[-1]) if len(ends) else 0

    @property
    def attrs(self) -> dict:
        return dict(self.root.attrs)

    @property
    def depth_spec(self) -> DepthSpec:
        return DepthSpec.from_dict(self.root.attrs["depth_spec"])

    def episode_slice(self, i: int) -> slice:
        ends = self.episode_ends
        if not -len(ends) <= i < len(ends):
            raise IndexError(f"episode {i} out of range (store has {len(ends)})")
        i %= len(ends)
        return slice(int(ends[i - 1]) if i else 0, int(ends[i]))

    def episode(self, i: int) -> dict[str, np.ndarray]:
        """All per-step arrays of episode ``i`` plus its meta (randomisation decoded)."""
        sl = self.episode_slice(i)
        out: dict = {name: arr[sl] for name, arr in self._data_arrays().items()}
        for name in _META:
            out[name] = self.root[f"meta/{name}"][i]
        out["kind"], out["randomisation"] = str(out["kind"]), json.loads(str(out["randomisation"]))
        return out

    def _data_arrays(self) -> dict[str, zarr.Array]:
        return {name: arr for name, arr in self.root["data"].arrays()}

    # --- depth sources ------------------------------------------------------------------------------
    @property
    def depth_sources(self) -> list[str]:
        """The depth sources whose array this store holds (generated ones possibly unfinished)."""
        return [name for name in DEPTH_SOURCES if self._array(name) in self.root]

    def _array(self, source: str) -> str:
        """Where ``source``'s frames are: a store collected under the source as its sensor (a DAgger round
        that drove on them) holds them as the sensor's frames, not as a generator's."""
        sensor = str(self.attrs.get("sensor", "")).split(":")[0]
        return DEPTH_SOURCES["sensor" if source == sensor and generator_of(source) else source].array

    def depth(self, source: str, steps: int) -> np.ndarray:
        """The first ``steps`` frames of depth ``source`` (``check_depth``)."""
        return np.asarray(self.root[self.check_depth(source, steps)][:steps])

    def check_depth(self, source: str, steps: int) -> str:
        """The array of depth ``source``; refused if the store lacks it or if its generator has not made its
        first ``steps`` frames yet (chunks no shard has reached are zeros)."""
        if source not in DEPTH_SOURCES:
            raise DatasetError(f"unknown depth source {source!r}; choose one of {sorted(DEPTH_SOURCES)}")
        array = self._array(source)
        if array not in self.root:
            held, maker = ", ".join(self.depth_sources), DEPTH_SOURCES[source]
            made_by = maker.labelled_by if maker.labelled_by and "data/labels" in self.root else maker.made_by
            raise DatasetError(f"{self.path} has no {array} for depth source {source!r} (make it with "
                               f"`{made_by}`); it holds {held}")
        generator = generator_of(source)
        if generator and array == DEPTH_SOURCES[source].array and _done(generator) in self.root:
            self._check_generated(generator, array, steps)
        return array

    # --- generated depth (trainer.ddg.generate) -----------------------------------------------------
    def generated_with(self, generator: str) -> dict | None:
        """The settings the store's depth of ``generator`` was made with, None before its first run."""
        return self.root.attrs.get(generator)

    def drop_generated(self, generator: str) -> None:
        """Delete ``generator``'s depth, its record of made chunks and its settings (to make it again
        otherwise)."""
        for name in (*(DEPTH_SOURCES[s].array for s in GENERATORS[generator]), _done(generator)):
            if name in self.root:
                del self.root[name]
        self.root.attrs.pop(generator, None)

    def generation_outputs(self, generator: str, settings: dict, chunk: int
                           ) -> tuple[dict[str, zarr.Array], zarr.Array]:
        """Each source ``generator`` makes -> its array (as long as ``data/depth``, zarr chunks of ``chunk``
        frames) and the per-chunk record of which are made, created on the first run with ``settings``
        recorded; episodes appended since the last run lengthen them. The caller checks ``settings`` against
        ``generated_with`` first."""
        if self.generated_with(generator) is None:
            self.root.attrs[generator] = settings
        shape = self.root["data/depth"].shape
        n_chunks = -(-shape[0] // chunk)
        if _done(generator) in self.root:
            self._grow_generated(generator, shape, n_chunks, chunk)
        outs = {s: self.root.require_array(DEPTH_SOURCES[s].array, shape=shape, dtype="uint16",
                                           chunks=(chunk, *shape[1:]), fill_value=0)
                for s in GENERATORS[generator]}
        done = self.root.require_array(_done(generator), shape=(n_chunks,), dtype="bool", chunks=(1,),
                                       fill_value=False)
        return outs, done

    def _grow_generated(self, generator: str, shape: tuple[int, ...], n_chunks: int, chunk: int) -> None:
        """Episodes appended since the last run (``collect`` resumed into the store): lengthen the outputs and
        the chunk record; a chunk that was the last, partial one then has new frames, so it is to be made
        again (frames are seeded by index: its old frames come out the same)."""
        sources = GENERATORS[generator]
        old = self.root[DEPTH_SOURCES[sources[0]].array].shape[0]
        if old == shape[0]:
            return
        for source in sources:
            self.root[DEPTH_SOURCES[source].array].resize(shape)
        done = self.root[_done(generator)]
        done.resize((n_chunks,))
        if old % chunk:
            done[old // chunk] = False

    def _check_generated(self, generator: str, array: str, frames: int) -> None:
        """Raise unless the generated ``array`` of the first ``frames`` frames is all made: frames appended
        since the last run are missing."""
        generate = f"`python -m trainer ddg generate --generator {generator} --demos {self.path}`"
        generated = self.root[array].shape[0]
        if generated < frames:
            raise DatasetError(f"{self.path}: {array} holds {generated} frames, the episodes {frames}: the "
                               f"store grew since its depth was generated; run {generate} again")
        chunk = int(self.generated_with(generator)["chunk"])
        needed = -(-frames // chunk)
        missing = np.flatnonzero(~np.asarray(self.root[_done(generator)][:needed]))
        if missing.size:
            raise DatasetError(
                f"{self.path}: {generator} depth of {missing.size} of the {needed} chunks ({chunk} frames "
                f"each) that these episodes span is not generated yet (first: chunk {missing[0]}); finish it "
                f"with {generate}, or train on fewer episodes (--episodes)")
