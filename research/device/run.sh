#!/bin/bash
# Device run of `trainer student recipe` (not part of the product): carried wheels and GL loaders, the cache files
# carried under .devsite/cache (e.g. M0's checkpoint for --head) put where they are here, a recipe folder carried
# in parts (research/device/pack.py, split; one part under .stash<k>/ a call, the machine kept warm between
# calls) unpacked, a probe of the GPU's fit rate in the recipe's --precision that sizes round 0's fit to FIT0_S
# seconds (FIT0_STEPS: a resume repeats its steps), then the recipe, stopped in time to bring back what a CPU
# resume needs under $OUT.
#   usage: research/device/run.sh BUDGET_S FIT0_S ROUND_STEPS NAME [recipe flags]
#   BUDGET_S 0: only set up and keep the carried part; PRECOLLECT=1 also collects the hover episodes and round
#   0's demos in the background from NAME's recipe.json (the largest stores: 15 workers collect them faster than
#   they travel). Every call carries .devsite: an ignored folder not carried is removed there.
BUDGET=$1; FIT0_S=$2; FITR=$3; NAME=$4; shift 4
T0=$(date +%s)
if command -v nvidia-smi > /dev/null && [ ! -f /tmp/site/.installed ]; then  # the device: loaders and wheels
    for f in .gl/*.deb; do dpkg -x "$f" / ; done; ldconfig
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        || exit 3
    touch /tmp/site/.installed
fi
export PYTHONPATH=/tmp/site:$PWD/.devsite:$PWD MUJOCO_GL=egl PYTHONUNBUFFERED=1 TQDM_MININTERVAL=15
CACHE=$HOME/.cache/diffudepgrasp
REC=$CACHE/recipe/$NAME
mkdir -p "$CACHE" /tmp/stash && { [ -d .devsite/cache ] && cp -r .devsite/cache/. "$CACHE/"; }
check() { python3 - <<'PY'
from trainer.sim.env import GraspEnv, EnvConfig
e = GraspEnv(EnvConfig()); o, i = e.reset(seed=1); print("render ok", i["depth"].shape, int(i["depth"].max()))
PY
}
render() {  # the NVIDIA EGL vendor file where the loader finds none by itself
    check || { export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json; check || exit 4; }
}
compgen -G ".stash*/part.*" > /dev/null && cp .stash*/part.* /tmp/stash/ && ls -l /tmp/stash
if [ -n "$PRECOLLECT" ]; then
    render
    setsid nohup bash -c "echo \$\$ > /tmp/round0.pid; python3 -c 'import json; from pathlib import Path
from trainer.student.recipe import Recipe, RecipeConfig
out = Path(\"$REC\"); cfg = RecipeConfig(**{**json.loads((out / \"recipe.json\").read_text()), \"workers\": 15})
r = Recipe(out, cfg); r.hover(); r.collect(0)' && touch /tmp/round0.done" > /tmp/round0.log 2>&1 < /dev/null &
    sleep 15; cat /tmp/round0.log
fi
[ "$BUDGET" = 0 ] && exit 0
if compgen -G "/tmp/stash/part.*" > /dev/null && [ ! -f /tmp/stash/.unpacked ]; then
    cat /tmp/stash/part.* | tar x -C "$CACHE/recipe" && touch /tmp/stash/.unpacked || exit 5
fi
if [ -f /tmp/round0.log ]; then  # the background demos: wait for them (the recipe would collect what is missing)
    while [ ! -f /tmp/round0.done ] && kill -0 "$(cat /tmp/round0.pid)" 2> /dev/null; do sleep 5; done
    echo "round 0 demos ready after $(( $(date +%s) - T0 ))s"; tail -c 300 /tmp/round0.log; echo
fi
render
get() { local k=$1 d=$2; shift 2; while [ $# -gt 0 ]; do [ "$1" = "$k" ] && { echo "$2"; return; }; shift; done; echo "$d"; }
[ -z "$FIT0_STEPS" ] && RATE=$(python3 research/fit_precision.py --width "$(get --width 16 "$@")" \
    --batch "$(get --batch 128 "$@")" --threads "$(nproc)" --repeats 20 \
    | python3 -c "import json, sys; print(round(1 / json.load(sys.stdin)['$(get --precision fp32 "$@")_s_per_step'], 2))")
[ -z "$FIT0_STEPS" ] && echo "fit rate ${RATE} it/s on $(nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null || echo cpu)"
FIT0=${FIT0_STEPS:-$(python3 -c "print(max(100, int($RATE * $FIT0_S)))")}  # FIT0_STEPS: a resume repeats its steps
LEFT=$(( BUDGET - ($(date +%s) - T0) - 25 ))
echo "round 0: ${FIT0} steps, rounds: ${FITR}; recipe budget ${LEFT}s"
touch /tmp/recipe.start  # what changes after this travels back
timeout -s INT $LEFT python3 -m trainer student recipe --name "$NAME" --fit-steps "$FIT0" --round-steps "$FITR" "$@" \
    > "$OUT/recipe.log" 2>&1
echo "recipe rc $? after $(( $(date +%s) - T0 ))s"
grep '^{' "$OUT/recipe.log" | tail -20
python3 research/device/pack.py "$REC" /tmp/recipe.tar --newer /tmp/recipe.start || exit 6
split -b 15m /tmp/recipe.tar "$OUT/recipe.tar."
ls -la "$OUT"; echo "done after $(( $(date +%s) - T0 ))s"
