"""Paired depth of the same views, the simulator's (clean) and a sensor's, read from demo stores: what the
residual diffusion (Stable-Sim2Real) and its patch discriminator learn from.

The stereo sensor's pairs come from a labelled store made under it::

    python -m trainer student readout CKPT --store S.zarr --episodes N --no-chunks --sensor stereo --seed SEED

Paired real data (a real camera beside a simulator's render of the same scene) goes in a zarr group of the
demo store's layout (``trainer.dataset``); only these of it are read:

    data/depth          uint16  [N, H, W]  the simulator's depth of each view, mm, 0 = none
    data/depth_sensor   uint16  [N, H, W]  the sensor's depth of the same view and crop, mm, 0 = no data
    meta/episode_ends   int64   [E]        cumulative end index of each sequence of views
    meta/camera_K       float64 [E, 3, 3]  the stream's pinhole intrinsics (pixels) of each sequence
    meta/crop_window    int32   [E, 2]     (top, left) of the policy's crop in that stream
    attrs["depth_spec"]                    ``runtime.preprocess.DepthSpec.to_dict()``: stream, crop, H x W

Every ``holdout_every``-th episode of each store is held out (never trained on); the accuracy reports read it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hil_sim.camera import Intrinsics
from runtime.preprocess import DepthSpec
from trainer.dataset import DatasetError, DemoStore, sizes

PARTS = ("train", "heldout")


class PairedDataError(ValueError):
    """A store that cannot give paired frames: missing, without the sensor's frames, or of another view."""


@dataclass(frozen=True)
class Pairs:
    """Paired frames: ``sim`` and ``real`` uint16 mm [N, H, W], ``K`` float64 [N, 3, 3] the intrinsics of each
    frame at its own resolution (its crop window's), ``spec`` their DepthSpec."""

    sim: np.ndarray
    real: np.ndarray
    K: np.ndarray
    spec: DepthSpec

    def __len__(self) -> int:
        return len(self.sim)


def policy_K(camera_K: np.ndarray, window: tuple[int, int], spec: DepthSpec) -> np.ndarray:
    """The pinhole K of the policy's frames: the stream's ``camera_K`` seen through the crop ``window`` and
    resized to ``spec``'s resolution (``hil_sim.camera.Intrinsics.window``, the crop's one geometry)."""
    stream = Intrinsics(spec.stream_width, spec.stream_height, float(camera_K[0, 0]), float(camera_K[1, 1]),
                        float(camera_K[0, 2]), float(camera_K[1, 2]))
    return stream.window(int(window[0]), int(window[1]), spec).K


def load_pairs(stores: tuple[str, ...], part: str = "train", holdout_every: int = 10, stride: int = 1
               ) -> Pairs:
    """The paired frames of ``part`` ("train" or "heldout") of ``stores``: every ``stride``-th step of each
    episode; episode i of a store is held out when ``holdout_every`` > 0 and (i + 1) % holdout_every == 0."""
    if part not in PARTS:
        raise PairedDataError(f"part must be one of {PARTS}, got {part!r}")
    if not stores:
        raise PairedDataError("no store given (--store S.zarr; see trainer/ddg/pairs.py for the layout)")
    if stride < 1 or holdout_every < 0:
        raise PairedDataError(f"need stride >= 1 and holdout_every >= 0, got {stride} and {holdout_every}")
    read = [_read(_open(path), part, holdout_every, stride) for path in stores]
    specs = {spec for *_, spec in read}
    if len(specs) > 1:
        raise PairedDataError(f"stores of different views cannot be mixed: {sorted(map(sizes, specs))}")
    if not sum(len(sim) for sim, *_ in read):
        raise PairedDataError(f"no {part} episodes in {', '.join(stores)} (every {holdout_every}-th episode "
                              "is held out: --holdout-every)")
    sim, real, K = (np.concatenate([r[i] for r in read]) for i in range(3))
    return Pairs(sim, real, K, specs.pop())


def _open(path: str) -> DemoStore:
    try:
        store = DemoStore.open(path)
    except DatasetError as exc:
        raise PairedDataError(str(exc)) from None
    for array in ("data/depth", "data/depth_sensor", "meta/camera_K", "meta/crop_window"):
        if array not in store.root:
            raise PairedDataError(f"{path}: no {array}, so no paired frames (make one with `python -m "
                                  "trainer student readout CKPT --store S.zarr --no-chunks --sensor stereo`)")
    shapes = {store.root[a].shape for a in ("data/depth", "data/depth_sensor")}
    if len(shapes) > 1:
        raise PairedDataError(f"{path}: data/depth and data/depth_sensor differ in shape {sorted(shapes)}")
    return store


def _read(store: DemoStore, part: str, holdout_every: int, stride: int
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, DepthSpec]:
    spec, root = store.depth_spec, store.root
    held = [holdout_every > 0 and (i + 1) % holdout_every == 0 for i in range(store.n_episodes)]
    picked = [i for i, h in enumerate(held) if h == (part == "heldout")]
    sims, reals, Ks = [], [], []
    for i in picked:
        steps = store.episode_slice(i)
        steps = slice(steps.start, steps.stop, stride)
        sims.append(np.asarray(root["data/depth"][steps]))
        reals.append(np.asarray(root["data/depth_sensor"][steps]))
        K = policy_K(root["meta/camera_K"][i], tuple(root["meta/crop_window"][i]), spec)
        Ks.append(np.repeat(K[None], len(sims[-1]), axis=0))
    empty = np.zeros((0, spec.out_height, spec.out_width), np.uint16)
    if not picked:
        return empty, empty, np.zeros((0, 3, 3)), spec
    return np.concatenate(sims), np.concatenate(reals), np.concatenate(Ks), spec

