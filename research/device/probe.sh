#!/bin/bash
# Fit-rate probe of the recipe's depth student on the device: fp32 (TF32) against bf16 autocast, two batch sizes.
for f in .gl/*.deb; do dpkg -x $f / ; done; ldconfig  # EGL loaders: importing the trainer imports MuJoCo
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 3
export PYTHONPATH=/tmp/site:$PWD/.devsite:$PWD PYTHONUNBUFFERED=1
python3 - <<'PY'
import time, torch
from trainer.student.config import StudentConfig
from trainer.student.model import PerceptionStudent
from trainer.student.distill import DistillConfig, losses
from trainer.student.ddim import training_scheduler
from trainer.student.steps import StepBatch
dev = torch.device("cuda")
print(torch.cuda.get_device_name(0), torch.__version__)
cfg = StudentConfig(perception="depth", width=32, head_dims=(32, 64, 128), state_features=128,
                    prediction="v_prediction", exec_horizon=4)
sch = training_scheduler(100, "v_prediction")
for B in (256, 1024):
    for amp in (False, True):
        net = PerceptionStudent(cfg).to(dev); opt = torch.optim.AdamW(net.parameters(), 3e-4)
        gen = torch.Generator(device=dev).manual_seed(0)
        b = StepBatch(torch.rand(B, 3, 96, 128, device=dev), torch.rand(B, 8, device=dev),
                      torch.rand(B, 12, device=dev) * 2 - 1, torch.rand(B, 16, 8, device=dev))
        for i in range(35):
            if i == 10:
                torch.cuda.synchronize(); t = time.perf_counter()
            with torch.autocast("cuda", dtype=torch.bfloat16, enabled=amp):
                loss, _ = losses(net, sch, b, gen, DistillConfig())
            opt.zero_grad(); loss.backward(); opt.step()
        torch.cuda.synchronize(); rate = 25 / (time.perf_counter() - t)
        print(f"batch {B} bf16 {amp}: {rate:.1f} it/s, {rate * B:.0f} samples/s, loss {float(loss):.3f}")
PY
