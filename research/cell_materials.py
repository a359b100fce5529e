"""Do the stereo sensor's dark or shiny objects lose a cell's grasps (issue 45)? Each episode of a ``trainer
evaluate --sensor stereo`` result, split by the IR material the sensor drew for its object (ordinary, dark:
few dots return, shiny: specular), success with 95 % Wilson intervals.

    PYTHONPATH=. python research/cell_materials.py CELL.json [CELL.json ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hil_sim.stereo import StereoParams
from hil_sim.stereo.ir import MATERIAL_KINDS
from hil_sim.stereo.sensor import episode_material
from trainer.eval.compare import episodes
from trainer.eval.stats import wilson_interval


def by_material(cell: Path, params: StereoParams) -> dict:
    kinds, failed, policy = episodes(cell)
    drawn = {s: episode_material(s, params) for s in kinds}
    rows = {}
    for material in MATERIAL_KINDS:
        seeds = [s for s in kinds if drawn[s] == material]
        won = sum(s not in failed for s in seeds)
        rows[material] = {"grasped": won, "episodes": len(seeds),
                          "ci95": [round(x, 3) for x in wilson_interval(won, len(seeds))]}
    return {"cell": str(cell), "policy": policy, "by_material": rows}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("cells", type=Path, nargs="+", help="trainer evaluate results run under --sensor stereo")
    args = p.parse_args()
    params = StereoParams.load()
    for cell in args.cells:
        print(json.dumps(by_material(cell, params)))


if __name__ == "__main__":
    main()
