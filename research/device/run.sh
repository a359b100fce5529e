#!/bin/bash
# Device run of `trainer student recipe` (not part of the product): carried wheels and GL loaders, the cache files
# carried under .devsite/cache (e.g. M0's checkpoint for --head) put where they are here, a probe of the GPU's fit
# rate that sizes round 0's fit to FIT0_S seconds, then the recipe with 15 rollout workers, stopped in time to bring
# back what a CPU resume needs: each round's checkpoint (EMA weights only) and results, split under $OUT.
#   usage: research/device/run.sh BUDGET_S FIT0_S ROUND_STEPS NAME [recipe flags]
BUDGET=$1; FIT0_S=$2; FITR=$3; NAME=$4; shift 4
T0=$(date +%s)
if command -v nvidia-smi > /dev/null; then  # on the device only: the carried GL loaders and wheels
    for f in .gl/*.deb; do dpkg -x "$f" / ; done; ldconfig
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        || exit 3
fi
export PYTHONPATH=/tmp/site:$PWD/.devsite:$PWD MUJOCO_GL=egl PYTHONUNBUFFERED=1 TQDM_MININTERVAL=15
CACHE=$HOME/.cache/diffudepgrasp
mkdir -p "$CACHE" && { [ -d .devsite/cache ] && cp -r .devsite/cache/. "$CACHE/"; }
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
from trainer.student.distill import DistillConfig, device, losses
from trainer.student.ddim import training_scheduler
from trainer.student.steps import StepBatch
a = sys.argv[1:]
get = lambda k, d: a[a.index(k) + 1] if k in a else d
cfg = StudentConfig(perception="depth", width=int(get("--width", 16)), head_dims=(32, 64, 128), state_features=128,
                    prediction="v_prediction", exec_horizon=4)
B, dev = int(get("--batch", 128)), device()
net = PerceptionStudent(cfg).to(dev); opt = torch.optim.AdamW(net.parameters(), 3e-4)
sch = training_scheduler(100, "v_prediction"); sch.alphas_cumprod = sch.alphas_cumprod.to(dev)
gen = torch.Generator(device=dev).manual_seed(0)
b = StepBatch(torch.rand(B, 3, 96, 128, device=dev), torch.rand(B, 8, device=dev), torch.rand(B, 12, device=dev) * 2 - 1,
              torch.rand(B, 16, 8, device=dev))
sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
for i in range(30):
    if i == 10: sync(); t = time.perf_counter()
    loss, _ = losses(net, sch, b, gen, DistillConfig(shift_px=4)); opt.zero_grad(); loss.backward(); opt.step()
sync(); print(round(20 / (time.perf_counter() - t), 2))
PY
)
echo "fit rate ${RATE} it/s on $(nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null || echo cpu)"
FIT0=${FIT0_STEPS:-$(python3 -c "print(max(100, int($RATE * $FIT0_S)))")}  # FIT0_STEPS: a resume repeats its steps
LEFT=$(( BUDGET - ($(date +%s) - T0) - 25 ))
echo "round 0: ${FIT0} steps, rounds: ${FITR}; recipe budget ${LEFT}s"
timeout -s INT $LEFT python3 -m trainer student recipe --name "$NAME" --fit-steps "$FIT0" --round-steps "$FITR" "$@" \
    > "$OUT/recipe.log" 2>&1
echo "recipe rc $? after $(( $(date +%s) - T0 ))s"
grep '^{' "$OUT/recipe.log" | tail -20
python3 - "$CACHE/recipe/$NAME" <<'PY'
import sys, tarfile, torch
from pathlib import Path
rec = Path(sys.argv[1])
with tarfile.open("/tmp/recipe.tgz", "w:gz") as tar:
    for path in sorted(rec.rglob("*")):
        if ("data" in path.relative_to(rec).parts or path.is_dir() or path.suffix in (".onnx", ".tmp")
                or path.name == "composed.pt"):
            continue  # stores are too large to travel (a CPU resume collects them again); exports are redone
        if path.name == "ckpt.pt":
            c = torch.load(path, map_location="cpu", weights_only=True)
            torch.save({**c, "model": c["ema"], "optimizer": None}, "/tmp/slim.pt")  # shared tensors saved once
            print(path.parent.name, "step", c["step"])
            tar.add("/tmp/slim.pt", arcname=str(path.relative_to(rec.parent)))
        else:
            tar.add(path, arcname=str(path.relative_to(rec.parent)))
PY
split -b 15m /tmp/recipe.tgz "$OUT/recipe.tgz."
ls -la "$OUT"; echo "done after $(( $(date +%s) - T0 ))s"
