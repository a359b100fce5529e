"""Upright cylinders as user-object MJCF files, of the can's and wheel's type, which the product's training
shapes leave out so that those kinds stay of an unseen type.

What they measure: which round, flat-topped objects the readout misreads (it read the can as elongated), by
size, without training on them. Read on expert episodes (``trainer student readout CKPT --store S --objects
PATH,...``), cylinders as tall as the training kinds read round once square boxes that tall were trained on,
and a cylinder as tall as the can (12 cm) as elongated until square boxes that tall were (``docs/history.md``,
2026-11-30). The files are ordinary ``--objects PATH,...`` user objects (category 13, like the shapes):

    python research/cylinder_shapes.py --out ~/.cache/diffudepgrasp/cylinders      # prints the comma list
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from hil_sim.objects import MIN_HALF, SHAPE_DENSITY


def cylinder_xml(name: str, radius: float, half_height: float, rng: np.random.Generator) -> str:
    """One upright cylinder (4-7.2 cm across, at most twice as tall as wide, so it stands), weighed as a
    training shape."""
    mass = float(np.clip(SHAPE_DENSITY * math.pi * radius ** 2 * 2 * half_height, 0.05, 0.35))
    rgba = " ".join(f"{v:.2f}" for v in rng.uniform(0.15, 0.95, 3))
    friction = rng.uniform(0.7, 1.0)
    return (f'<mujoco model="{name}"><worldbody><body name="{name}">'
            f'<geom type="cylinder" size="{radius:.4f} {half_height:.4f}" mass="{mass:.3f}" '
            f'friction="{friction:.2f} 0.005 0.0001" rgba="{rgba} 1"/></body></worldbody></mujoco>\n')


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="folder for cyl00.xml ...")
    p.add_argument("--count", type=int, default=8)
    p.add_argument("--seed", type=int, default=2)
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    paths = []
    for i in range(a.count):
        radius = rng.uniform(MIN_HALF, 0.036)
        half_height = rng.uniform(0.015, min(0.065, 2 * radius))
        path = a.out / f"cyl{i:02d}.xml"
        path.write_text(cylinder_xml(f"cyl{i:02d}", radius, half_height, rng))
        paths.append(str(path))
    print(",".join(paths))


if __name__ == "__main__":
    main()
