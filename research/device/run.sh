#!/bin/bash
# Device run of `trainer student recipe` (not part of the product): carried wheels and GL loaders, a probe of the
# GPU's fit rate that sizes the fits to the time left, then the recipe with 15 rollout workers, stopped in time to
# bring its newest exported round back under $OUT.   usage: research/device/run.sh BUDGET_S FIT0_S FITR_S [recipe flags]
BUDGET=$1; FIT0_S=$2; FITR_S=$3; shift 3
T0=$(date +%s)
for f in .gl/*.deb; do dpkg -x $f / ; done; ldconfig
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 3
export PYTHONPATH=/tmp/site:$PWD/.devsite:$PWD MUJOCO_GL=egl PYTHONUNBUFFERED=1
check() { python3 - <<'PY'
from trainer.sim.env import GraspEnv, EnvConfig
e = GraspEnv(EnvConfig()); o, i = e.reset(seed=1); print("render ok", i["depth"].shape, int(i["depth"].max()))
PY
}
check || { export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json; check || exit 4; }
RATE=$(python3 - "$@" <<'PY'
import sys, time, torch
from trainer.student.config import StudentConfig
from trainer.student.model import PerceptionStudent
from trainer.student.distill import DistillConfig, losses
from trainer.student.ddim import training_scheduler
from trainer.student.steps import StepBatch
a = sys.argv[1:]
get = lambda k, d: a[a.index(k) + 1] if k in a else d
cfg = StudentConfig(perception="depth", width=int(get("--width", 16)), head_dims=(32, 64, 128), state_features=128,
                    prediction="v_prediction", exec_horizon=4)
B, dev = int(get("--batch", 64)), torch.device("cuda")
net = PerceptionStudent(cfg).to(dev); opt = torch.optim.AdamW(net.parameters(), 3e-4)
sch = training_scheduler(100, "v_prediction"); gen = torch.Generator(device=dev).manual_seed(0)
b = StepBatch(torch.rand(B, 3, 96, 128, device=dev), torch.rand(B, 8, device=dev), torch.rand(B, 12, device=dev) * 2 - 1,
              torch.rand(B, 16, 8, device=dev))
for i in range(40):
    if i == 10: torch.cuda.synchronize(); t = time.perf_counter()
    loss, _ = losses(net, sch, b, gen, DistillConfig()); opt.zero_grad(); loss.backward(); opt.step()
torch.cuda.synchronize(); print(round(30 / (time.perf_counter() - t), 1))
PY
)
echo "fit rate ${RATE} it/s ($(nvidia-smi --query-gpu=name --format=csv,noheader))"
FIT0=$(python3 -c "print(max(500, int($RATE * $FIT0_S)))"); FITR=$(python3 -c "print(max(300, int($RATE * $FITR_S)))")
REC=/tmp/recipe
LEFT=$(( BUDGET - ($(date +%s) - T0) - 40 ))
echo "fit steps ${FIT0} / ${FITR}; recipe budget ${LEFT}s"
timeout -s INT $LEFT python3 -m trainer student recipe --out $REC --fit-steps $FIT0 --round-steps $FITR "$@" > $OUT/recipe.log 2>&1
echo "recipe rc $? after $(( $(date +%s) - T0 ))s"
grep -v "it/s\|ep/s\|s/ep\|s/it" $OUT/recipe.log | tail -25
cp $REC/log.jsonl $REC/learning_curve.* $REC/recipe.json $OUT/ 2>/dev/null
LAST=""
for d in $(ls -d $REC/fit/round* | sort -V -r); do [ -f $d/student.onnx ] && { LAST=$d; break; }; done
echo "newest exported round: $LAST"
python3 - "$LAST" <<'PY'
import sys, torch
from pathlib import Path
d = Path(sys.argv[1])
c = torch.load(d / "ckpt.pt", map_location="cpu", weights_only=True)
slim = {**c, "model": c["ema"], "optimizer": None}
torch.save(slim, "/tmp/ckpt.pt")
print(d.name, "step", c["step"])
PY
tar czf /tmp/student.tgz -C $LAST student.onnx loss.png -C /tmp ckpt.pt && split -b 15m /tmp/student.tgz $OUT/student.tgz.
ls -la $OUT; echo "done after $(( $(date +%s) - T0 ))s"
