"""Pack a recipe folder into a tar that fits the device's transfer limits (not part of the product).

Finished checkpoints travel slim (EMA weights as the model, no optimiser: a third of the size); a checkpoint
short of its round's steps stays behind (a slim one could not resume its fit); exports and composed
checkpoints stay behind (the recipe redoes them in seconds); stores travel only where named.

    python research/device/pack.py RECIPE_DIR OUT.tar [--stores round1 round2 hover] [--newer FILE]

``--newer FILE`` takes only what changed after FILE did (what a run made), the learner's round stores too;
not the expert's demos and hover episodes (collected again from their seeds, they come out identical) nor
the held-out stores (a readout's 30 episodes). The tar holds paths below RECIPE_DIR's parent, so it unpacks
into ``~/.cache/diffudepgrasp/recipe``.
"""
import argparse
import io
import json
import tarfile
from pathlib import Path

import torch

REBUILT = {"round0", "hover"}
"""The expert's stores: a resume collects them again from their seeds, identical, faster than they travel."""


def steps_due(recipe: Path, round_dir: str) -> int:
    settings = json.loads((recipe / "recipe.json").read_text())
    return settings["fit_steps"] if round_dir == "round0" else settings["round_steps"]


def slim(c: dict) -> bytes:
    buf = io.BytesIO()
    torch.save({**c, "model": c["ema"], "optimizer": None}, buf)  # shared tensors are saved once
    return buf.getvalue()


def travels(rel: Path, stores: set[str], new: bool | None) -> bool:
    """``new``: whether the file changed since ``--newer``'s file did; None without ``--newer``."""
    if rel.suffix in (".onnx", ".tmp") or rel.name == "composed.pt":
        return False
    if rel.parts[0] == "data":
        store = rel.parts[1].removesuffix(".zarr")
        return store in stores or bool(new and store not in REBUILT and not store.startswith("held_out"))
    return new is not False


def pack(recipe: Path, out: Path, stores: set[str], since: float | None) -> None:
    with tarfile.open(out, "w") as tar:  # the stores are compressed already
        for path in sorted(recipe.rglob("*")):
            name = str(path.relative_to(recipe.parent))
            new = None if since is None else path.stat().st_mtime > since
            if path.is_dir() or not travels(path.relative_to(recipe), stores, new):
                continue
            if path.name == "ckpt.pt":
                ckpt = torch.load(path, map_location="cpu", weights_only=True)
                if ckpt["step"] < steps_due(recipe, path.parent.name):
                    print(f"{name}: step {ckpt['step']}, unfinished: stays behind")
                    continue
                data = slim(ckpt)
                info = tarfile.TarInfo(name)
                info.size = len(data)
                tar.addfile(info, io.BytesIO(data))
            else:
                tar.add(path, arcname=name, recursive=False)
    print(f"{out}: {out.stat().st_size / 1e6:.1f} MB")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recipe", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--stores", nargs="*", default=[], help="store names under data/, without .zarr")
    p.add_argument("--newer", type=Path, help="only what changed after this file (default: everything)")
    a = p.parse_args()
    pack(a.recipe, a.out, set(a.stores), a.newer.stat().st_mtime if a.newer else None)


if __name__ == "__main__":
    main()
