"""``python -m hil_sim.stereo calibrate|bench|picture``: fit, time and show the active-stereo sensor.

  calibrate --real DIR --out hil_sim/stereo_params.json --report docs/stereo_calibration.json
  bench --frames 30                          cost per frame (render / IR + matching), median and p99
  picture --real DIR --out docs/stereo_vs_real.png
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from hil_sim import objects
from hil_sim.stereo.params import DEFAULT_PARAMS, StereoParams, StereoParamsError

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real_depth"


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m hil_sim.stereo", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    cal = sub.add_parser("calibrate", help="fit the free parameters to real D4xx frames")
    cal.add_argument("--real", type=Path, default=REAL, help="real_depth folder (default %(default)s)")
    cal.add_argument("--out", type=Path, default=DEFAULT_PARAMS, help="parameters file to write")
    cal.add_argument("--report", type=Path, help="also write the calibration figures as JSON here")
    cal.add_argument("--episodes", type=int, default=12, help="simulated scenes compared with the real ones")
    bench = sub.add_parser("bench", help="cost per frame over randomised scenes")
    bench.add_argument("--frames", type=int, default=30)
    bench.add_argument("--params", type=Path, help="parameters file (default: the shipped one)")
    pic = sub.add_parser("picture", help="real D415 frame beside simulated frames")
    pic.add_argument("--real", type=Path, default=REAL)
    pic.add_argument("--out", type=Path, default=Path("docs/stereo_vs_real.png"))
    pic.add_argument("--params", type=Path)
    return p.parse_args(argv)


def run_calibrate(args: argparse.Namespace) -> None:
    from hil_sim.stereo.calibrate import calibrate

    if args.episodes < 1:
        raise ValueError(f"--episodes must be at least 1, got {args.episodes}")
    cmd = shlex.join(["python", "-m", "hil_sim.stereo", *sys.argv[1:]])  # as a user would type it again
    params, report = calibrate(args.real, StereoParams(), args.episodes)
    params.save(args.out, command=cmd, fits=report["fits"])
    fits = report["fits"]
    summary = {k: fits["holes"][k] for k in ("ambient", "texture_threshold", "surface_texture")}
    print(json.dumps({**summary, "exposure_level": fits["exposure_level"], **fits["disparity_noise"],
                      **report["checks"]}))
    for key in ("hole_fraction", "holes_outside_band", "band_ratio", "holes_per_frame",
                "hole_size_p50_ppm", "hole_size_p90_ppm", "plane_sigma_px"):
        print(f"{key:24s} real {report['real'][key]!s:>10}   sim {report['sim'][key]!s:>10}")
    if args.report:
        args.report.write_text(json.dumps({"command": cmd, **report}, indent=1) + "\n")
    print(f"wrote {args.out}")


def run_bench(args: argparse.Namespace) -> None:
    from hil_sim.stereo.sensor import StereoSensor
    from hil_sim.world import World

    if args.frames < 1:
        raise ValueError(f"--frames must be at least 1, got {args.frames}")
    kinds = objects.GROUPS["all"]
    world, sensor = World(kinds), StereoSensor(StereoParams.load(args.params))
    world.reset(kinds[0], 0)
    sensor.reset(world, 0)
    sensor.stream(world)  # warm-up: GL context, pattern
    render, rest = [], []
    for i in range(args.frames):
        world.reset(kinds[i % len(kinds)], i)
        sensor.reset(world, i)
        t0 = time.perf_counter()
        seen = sensor.render(world)
        t1 = time.perf_counter()
        sensor.from_views(seen)
        render.append(t1 - t0)
        rest.append(time.perf_counter() - t1)
    total = 1e3 * (np.asarray(render) + np.asarray(rest))
    print(json.dumps({"frames": args.frames, "working_size": [sensor.rig.intr.width, sensor.rig.intr.height],
                      "total_ms_median": round(float(np.median(total)), 1),
                      "total_ms_p99": round(float(np.percentile(total, 99)), 1),
                      "render_ms_median": round(1e3 * float(np.median(render)), 1),
                      "ir_and_matching_ms_median": round(1e3 * float(np.median(rest)), 1)}))
    sensor.close()
    world.close()


def run_picture(args: argparse.Namespace) -> None:
    from hil_sim.stereo.calibrate import IR_PAIR
    from hil_sim.stereo.sensor import StereoSensor
    from hil_sim.world import World

    with np.load(args.real / IR_PAIR) as z:
        real_ir, real_depth = z["ir_left"], z["depth_m"]
    size = (424, 240)
    tiles = [[_label(cv2.resize(real_ir, size), "real D415: left IR"),
              _label(_colour(cv2.resize(real_depth, size, interpolation=cv2.INTER_NEAREST)), "real: depth")]]
    world, sensor = World(("can", "banana", "cube")), StereoSensor(StereoParams.load(args.params))
    for kind, seed, material in (("can", 3, "ordinary"), ("banana", 5, "dark"), ("cube", 7, "shiny")):
        world.reset(kind, seed)
        sensor.reset(world, seed)
        sensor.set_material(material)
        frame = sensor.frame(world)
        clean = np.where(np.isfinite(frame.clean_z), frame.clean_z, 0.0)
        tiles.append([_label(frame.ir_left, f"sim {kind} ({material}): left IR"),
                      _label(_colour(frame.depth_mm[::2, ::2] / 1000.0), "sim: stereo depth"),
                      _label(_colour(clean), "sim: exact depth")])
    sensor.close()
    world.close()
    tiles[0].append(np.zeros_like(tiles[1][0]))
    rows = [np.hstack(row) for row in tiles]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.vstack(rows))
    print(f"wrote {args.out}")


def _colour(depth_m: np.ndarray) -> np.ndarray:
    """Depth 0.3-1.6 m as a colour map, holes (0) black."""
    scaled = np.clip((depth_m - 0.3) / 1.3 * 255, 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    out[depth_m <= 0] = 0
    return out


def _label(image: np.ndarray, text: str) -> np.ndarray:
    out = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    cv2.putText(out, text, (5, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


COMMANDS = {"calibrate": run_calibrate, "bench": run_bench, "picture": run_picture}


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    try:
        COMMANDS[args.command](args)
    except (StereoParamsError, ValueError, RuntimeError, FileNotFoundError) as exc:
        print(f"hil_sim.stereo: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
