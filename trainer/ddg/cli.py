"""``python -m trainer ddg <command>`` (fit, generate, metrics, paired, vs-sensor, bench, residual-fit,
residual-disc): each command runs one function on the config its flags make
(``trainer.argspec.run_config``)."""

from __future__ import annotations

from trainer.argspec import run_config
from trainer.menu import Menu

MENU = Menu("python -m trainer ddg", {
    "fit": ("train the DDG on real captures (DDPM, eq. 8)", "trainer.ddg.train:fit"),
    "generate": ("add a generator's depth to a demo store: the DDG's (depth_ddg, depth_ddg_nograft) or the "
                 "residual diffusion's (depth_residual)", "trainer.ddg.generate:generate"),
    "metrics": ("realism of each depth source vs held-out real frames (Table I)",
                "trainer.eval.realism:run_metrics"),
    "paired": ("each source's depth against the exact depth of the same view (simulated captures)",
               "trainer.eval.paired_depth:paired"),
    "vs-sensor": ("each depth source against a simulated sensor's frames of the same views (a paired store)",
                  "trainer.eval.sensor_realism:vs_sensor"),
    "bench": ("generation throughput per session mode, batch and DDIM step count",
              "trainer.eval.ddg_throughput:bench"),
    "residual-fit": ("fit stage I or II of the residual depth diffusion (Stable-Sim2Real) on paired frames",
                     "trainer.ddg.residual_fit:fit_stage"),
    "residual-disc": ("fit the 3D patch discriminator (stage I vs the sensor); held-out accuracy by patch "
                      "and width", "trainer.ddg.discriminator:fit_discriminators"),
}, errors=(ValueError,), call=run_config)  # every DDG input error is a ValueError with a one-line message
main = MENU.main
