"""``python -m trainer ddg fit|generate|metrics|paired|bench``: a thin table of subcommands over the DDG
modules."""

from __future__ import annotations

import argparse
import importlib
import sys

from .args import add_dataclass_args, from_args

# subcommand -> (module, config class, runner, help). Modules load lazily: `generate` needs no training code.
SUBCOMMANDS = {
    "fit": ("trainer.ddg.train", "FitConfig", "fit", "train the DDG on real captures (DDPM, eq. 8)"),
    "generate": ("trainer.ddg.generate", "GenerateConfig", "generate",
                 "add depth_ddg / depth_ddg_nograft to a demo store"),
    "metrics": ("trainer.eval.realism", "MetricsConfig", "run_metrics",
                "realism of each depth source vs held-out real frames (Table I)"),
    "paired": ("trainer.eval.paired_depth", "PairedConfig", "paired",
               "each source's depth against the exact depth of the same view (simulated captures)"),
    "bench": ("trainer.eval.ddg_throughput", "BenchConfig", "bench",
              "generation throughput per session mode, batch and DDIM step count"),
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in SUBCOMMANDS:
        listing = "\n".join(f"  {name:<9} {help_}" for name, (*_, help_) in SUBCOMMANDS.items())
        print(f"usage: python -m trainer ddg <command> [--help]\n\ncommands:\n{listing}", file=sys.stderr)
        return 0 if argv[:1] in (["-h"], ["--help"]) else 2
    module_name, cls, runner, _ = SUBCOMMANDS[argv[0]]
    module = importlib.import_module(module_name)
    ns = _one_parser(argv[0]).parse_args(argv[1:])
    try:
        getattr(module, runner)(from_args(getattr(module, cls), ns))
    except ValueError as e:  # every DDG input error is a ValueError subclass with a one-line message
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


def _one_parser(name: str) -> argparse.ArgumentParser:
    module, cls, _, help_ = SUBCOMMANDS[name]
    p = argparse.ArgumentParser(prog=f"python -m trainer ddg {name}", description=help_)
    add_dataclass_args(p, getattr(importlib.import_module(module), cls))
    return p
