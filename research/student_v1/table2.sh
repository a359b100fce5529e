#!/usr/bin/env bash
# The paper's Table II analogue (issue 7): students trained on four depth sources with one budget, each run
# under the exact (clean) and the active-stereo (stereo) sensor on seen and unseen kinds.
#   research/student_v1/table2.sh train      the students (after train.sh steps 1-3: demos, GT student, DDG depth)
#   research/student_v1/table2.sh evaluate [NAME...]  every cell (of the students named) -> runs/table2/*.json
#                                       (skips cells already written)
#   research/student_v1/table2.sh table      docs/table2.json + the markdown table of the README
#   research/student_v1/table2.sh key [NAME...]  rows at 180 episodes per cell (30 per kind, as issue 7 asks; default
#                                       gt, ddg, ddg_b) -> runs/table2/key; `table` prefers these cells
#   research/student_v1/table2.sh reactive   a GT student on demos of the phase-free (reactive) expert, and its cells
#   research/student_v1/table2.sh dagger     the hand-target GT student, 8000 more steps of it, their clean cells and its
#                                       DDG fine-tune
#   research/student_v1/table2.sh dart       DART demos (noisy execution, clean labels), a GT student fine-tuned on them
#                                       beside one on the scripted demos alone, and their clean cells
#   research/student_v1/table2.sh looking    more scripted demos, a GT student fine-tuned on them like `dart`, its clean cells
#   research/student_v1/table2.sh handpose   the oracle (perfect perception, same head) with and without the hand's pose,
#                                       then a GT student given the hand's pose and the object's offset from it,
#                                       from scratch and fine-tuned further, and their clean cells
#   research/student_v1/table2.sh moredata   the hand-pose students on 3000 demos, from scratch, and their measures
#   research/student_v1/table2.sh sixk       the best of those on 6000 demos, and its measures
#   research/student_v1/table2.sh ddgb6k     the best GT student (6000 demos) fine-tuned on DDG (b) depth (8000 steps,
#                                       then 12000 more), their measures and stereo cells
#   research/student_v1/table2.sh ddgb_heldout  their object estimate on DDG (b) depth, held-out and training demos
#   research/student_v1/table2.sh ddgb6k_all DDG (b) depth of all 6000 demos (resumable)
#   research/student_v1/table2.sh ddgb4k     `ddgb6k`'s fine-tune on DDG (b) depth of the first 4000 demos (once
#                                       ddgb6k_all has reached them), its held-out object estimate and key cells
#   research/student_v1/table2.sh sensor [N] the ceiling of any generator of the stereo sensor: `ddgb6k`'s fine-tunes
#                                       on the sensor's own frames of the first N (default 1000) of the same demos,
#                                       its object estimate on the sensor's frames and key cells
#   research/student_v1/table2.sh best       Table II at the best recipe: `ddgb6k`'s fine-tunes on randnoise and on
#                                       DDG (b) without grafting, and the key cells of every source from that start
#   research/student_v1/table2.sh ddga6k     `ddgb6k`'s fine-tunes on DDG (a)'s depth (models/ddg, the real captures) of
#                                       the same 1000 demos, its held-out object estimate and key cells
#   research/student_v1/table2.sh nografta6k the same on DDG (a)'s depth without grafting, and its key cells
#   research/student_v1/table2.sh ddga192 [N]  `ddga6k`'s fine-tunes on DDG (a) depth of N (default 1000) demos at
#                                       192x144, from `finer`'s student, and its cells under both sensors
#   research/student_v1/table2.sh ddga192_short  its first 8000 steps alone, under both sensors
#   research/student_v1/table2.sh ddg_b      DDG variant (b)'s student: the demos' depth through models/ddg_stereo, then
#                                       the `train` fine-tune on it (after train.sh steps 1-2)
# The stages of the options retired in issue 42 (recovery demos of `trainer collect --teacher takeover:S.onnx`,
# --seen-turn, --seen-yaw, --first-frame, --keyframe-weight, --gt-share, an --init that adds state inputs or drops
# frames) are gone, with those parts of dagger, looking, handpose and wrist: `git show
# 6ec6cdf:research/student_v1/table2.sh` prints them as they ran.
# Stereo cells are of the sensor in hil_sim/stereo_params.json (second version, textured); the first version's
# cells are kept in runs/table2_v1 and docs/table2_v1.json.
# Budget: the GT student of train.sh step 2, fine-tuned 8000 steps at lr 1e-4 on each source's depth of the
# same 1000 demos (seed 0); `gt` is that GT student itself. Evaluation seeds 10000.. for every cell.
set -euo pipefail
export OMP_NUM_THREADS=1
CLEAN_EPISODES=${CLEAN_EPISODES:-100}
STEREO_EPISODES=${STEREO_EPISODES:-90}

finetune() {  # out demos depth-source threads [fit options...]: the table's budget, 8000 steps from the GT student
    local out=runs/student/$1 demos=$2 source=$3 threads=$4
    shift 4
    python -m trainer student fit --demos "$demos" --depth-source "$source" --out "$out" \
        --init runs/student/gt_1000_obj1/ckpt.pt --object-loss 1 --steps 8000 --batch 32 --lr 1e-4 \
        --warmup 200 --width 16 --head-dims 32 64 128 --threads "$threads" --ckpt-every 1000 "$@"
    python -m export "$out/ckpt.pt" --ddim-steps 4 --out "$out.onnx"
}

export_x4() {  # name: runs/student/NAME's checkpoint exported to run 4 of each 16-step chunk -> runs/student/NAME_x4.onnx
    python -m export "runs/student/$1/ckpt.pt" --ddim-steps 4 --exec-horizon 4 --out "runs/student/$1_x4.onnx"
}

train() {
    # ddg: train.sh step 4's first stage kept in its own folder (it ran on 2 threads; the others on 1)
    for run in "ddg ddg2_ft_8k 2" "randnoise randnoise_ft_8k 1" "ddg_nograft ddg_nograft_ft_8k 1"; do
        set -- $run
        finetune "$2" runs/sim/demos_seen.zarr "$1" "$3"
    done
}

# name policy-file restore
HPOS="--hand-pose --object-offset --hand-target --seen-offset"
# the best recipe's inputs and targets (docs/student.md@b8caf57 "3000 demos"): the hand's pose, the object's offset from it
# as estimated and as read by the head, and the hand target; word-split on purpose where it is used

STUDENTS=("gt runs/student/gt_1000_obj1.onnx none"
          "gt_inpaint runs/student/gt_1000_obj1.onnx inpaint"
          "ddg runs/student/ddg2_ft_8k.onnx none"
          "randnoise runs/student/randnoise_ft_8k.onnx none"
          "ddg_nograft runs/student/ddg_nograft_ft_8k.onnx none"
          "ddg2_ft_20k runs/student/ddg2_ft_20k.onnx none"  # the ddg student at 20000 steps (shipped until 2026-11-25)
          "gt_hand runs/student/gt_hand_more_8k.onnx none"  # `dagger` step 2
          "ddg_hand runs/student/ddg_hand_8k.onnx none"  # `dagger` step 3
          "ddg_b runs/student/ddg_b_ft_8k.onnx none"  # `ddg_b`: DDG (b), trained on the stereo sensor's frames
          # `moredata`: the best GT student so far (3000 demos, hand pose, seen offset, 48000 steps); `key` names it
          "gt3k_hpos_more_12k_x4 runs/student/gt3k_hpos_more_12k_x4.onnx none"
          # `ddgb6k`: the best GT student (6000 demos) fine-tuned on DDG (b) depth; `key` names it
          "ddgb6k_hpos_8k_x4 runs/student/ddgb6k_hpos_8k_x4.onnx none"
          "ddgb6k_hpos_more_12k_x4 runs/student/ddgb6k_hpos_more_12k_x4.onnx none"
          "ddgb4k_hpos_more_12k_x4 runs/student/ddgb4k_hpos_more_12k_x4.onnx none"  # `ddgb4k`
          "sensor_hpos_more_12k_x4 runs/student/sensor_hpos_more_12k_x4.onnx none"  # `sensor`
          # `best`: Table II at the best recipe, every source fine-tuned from the same GT start as `ddgb6k`
          "gt6k_hpos_more_12k_x4 runs/student/gt6k_hpos_more_12k_x4.onnx none"
          "gt6k_inpaint_x4 runs/student/gt6k_hpos_more_12k_x4.onnx inpaint"
          "randnoise6k_hpos_more_12k_x4 runs/student/randnoise6k_hpos_more_12k_x4.onnx none"
          "nograftb6k_hpos_more_12k_x4 runs/student/nograftb6k_hpos_more_12k_x4.onnx none"
          "ddga6k_hpos_more_12k_x4 runs/student/ddga6k_hpos_more_12k_x4.onnx none"  # `ddga6k`
          "nografta6k_hpos_more_12k_x4 runs/student/nografta6k_hpos_more_12k_x4.onnx none")  # `nografta6k`

cell() {  # name model restore sensor objects episodes [folder]
    local json=${7:-runs/table2}/$1_$4_$5_$6.json
    [ -f "$json" ] && return 0
    [ -f "$2" ] || { echo "skipped $json: $2 not trained yet"; return 0; }
    python -m trainer evaluate --policy "student:$2" --restore "$3" --sensor "$4" --objects "$5" \
        --episodes "$6" --workers "${WORKERS:-2}" --json "$json" > "${json%.json}.log" 2>&1
}

grow_demos() {  # from to episodes [seed [collect options...]]: a copy of a scripted demo store grown to more
    # episodes; collect resumes a partial store where it stopped: seed (default 30000) + attempts so far (the 1000 demos
    # are seeds 0..1001, then 31002..33006 make 3000, 33007..36013 make 6000; meta/seed records each episode's)
    [ -d "$2" ] || cp -r "$1" "$2"
    python -m trainer collect --episodes "$3" --seed "${4:-30000}" --workers 2 --out "$2" "${@:5}"
}

demos_3k() {
    grow_demos runs/sim/demos_seen.zarr runs/sim/demos_seen_3k.zarr 3000
}

heldout_60() {  # [WxH]: the 60 held-out demos (seeds 50000..) every held-out measure reads, made once; at 128x96
    # in runs/student/heldout_60.zarr, at another policy resolution in runs/student/heldout_60_WxH.zarr
    local out=runs/student/heldout_60${1:+_$1}.zarr
    [ -d "$out" ] || python -m trainer collect --episodes 60 --objects seen --seed 50000 --workers 2 \
        --resolution "${1:-128x96}" --out "$out"
}

chosen() {  # the STUDENTS entries named in $NAMES (all of them if it is empty)
    local student
    for student in "${STUDENTS[@]}"; do
        [[ -z "${NAMES:-}" || " $NAMES " == *" ${student%% *} "* ]] && echo "$student"
    done
    return 0
}

evaluate() {  # [name...]
    mkdir -p runs/table2
    local NAMES="$*"
    for sensor in clean stereo; do
        episodes=$([ "$sensor" = clean ] && echo "$CLEAN_EPISODES" || echo "$STEREO_EPISODES")
        for objects in seen unseen; do
            while read -r student; do
                set -- $student
                cell "$1" "$2" "$3" "$sensor" "$objects" "$episodes"
            done < <(chosen)
        done
    done
}

key() {  # [name...]: default gt, ddg and ddg_b (the paper's shape); stereo cells first, they are the point
    mkdir -p runs/table2/key
    local NAMES="${*:-gt ddg ddg_b}"
    for sensor in stereo clean; do
        for objects in seen unseen; do
            while read -r student; do
                set -- $student
                cell "$1" "$2" "$3" "$sensor" "$objects" 180 runs/table2/key
            done < <(chosen)
        done
    done
}

reactive() {  # the recipe of train.sh step 2's first 16000 steps, on the reactive expert's demos
    python -m trainer collect --teacher reactive --episodes 1000 --objects seen --workers 2 \
        --out runs/sim/demos_seen_reactive.zarr
    python -m trainer student fit --demos runs/sim/demos_seen_reactive.zarr --depth-source gt \
        --out runs/student/reactive_gt_16k --object-loss 1 --steps 16000 --batch 32 --lr 3e-4 --warmup 200 \
        --width 16 --head-dims 32 64 128 --threads 1 --ckpt-every 1000
    python -m export runs/student/reactive_gt_16k/ckpt.pt --ddim-steps 4 --out runs/student/reactive_gt_16k.onnx
    cell reactive_gt runs/student/reactive_gt_16k.onnx none clean seen 200
    cell reactive_gt runs/student/reactive_gt_16k.onnx none stereo seen "$STEREO_EPISODES"
}

ddg_b() {
    # The same demos (a copy: a store holds one DDG's depth) through DDG (b) at DDIM 5, as train.sh step 3 did
    # with DDG (a) (first run: one 1-core process beside train.sh step 2; frames are seeded by index, so the
    # two shards give the same depth)
    ddg_depth models/ddg_stereo runs/sim/demos_seen.zarr runs/sim/demos_seen_ddg_b.zarr
    python -m trainer student fit --demos runs/sim/demos_seen_ddg_b.zarr --depth-source ddg \
        --out runs/student/ddg_b_ft_8k --init runs/student/gt_1000_obj1/ckpt.pt --object-loss 1 --steps 8000 \
        --batch 32 --lr 1e-4 --warmup 200 --width 16 --head-dims 32 64 128 --threads 1 --ckpt-every 1000
    python -m export runs/student/ddg_b_ft_8k/ckpt.pt --ddim-steps 4 --out runs/student/ddg_b_ft_8k.onnx
}

fit() {  # out demos depth-source threads steps [more fit flags]: the GT student's recipe (table2 fine-tunes: --init)
    local out=$1 demos=$2 source=$3 threads=$4 steps=$5
    shift 5
    python -m trainer student fit --demos "$demos" --depth-source "$source" --out "runs/student/$out" \
        --object-loss 1 --hand-target --steps "$steps" --batch 32 --width 16 --head-dims 32 64 128 \
        --warmup 200 --threads "$threads" --ckpt-every 1000 "$@"
    python -m export "runs/student/$out/ckpt.pt" --ddim-steps 4 --out "runs/student/$out.onnx"
}

dagger() {
    # 1. The GT student of train.sh step 2's first 16000 steps, its object head also reading the hand's offset.
    fit gt_hand_16k runs/sim/demos_seen.zarr gt 2 16000 --lr 3e-4
    # 2. 8000 more steps from it (lr 1e-4, as the table's fine-tunes); the recovery demos it was run beside are retired.
    fit gt_hand_more_8k runs/sim/demos_seen.zarr gt 1 8000 --lr 1e-4 --init runs/student/gt_hand_16k/ckpt.pt
    for name in gt_hand_16k gt_hand_more_8k; do
        cell "$name" "runs/student/$name.onnx" none clean seen 200
    done
    # 3. It fine-tuned on the DDG depth of the 1000 demos, as `train`; its cells and gt_hand's (the same file as
    #    gt_hand_more_8k) come from `evaluate`.
    fit ddg_hand_8k runs/sim/demos_seen.zarr ddg 1 8000 --lr 1e-4 --init runs/student/gt_hand_more_8k/ckpt.pt
}

dart() {
    # DART demos (docs/student.md@b8caf57 "Not DART either"): the scripted expert with its joint commands executed under N(0, 0.3)
    # noise, its own actions stored; 500 successful episodes (seeds 20000..) appended to a copy of the 1000
    # scripted demos. The GT student fine-tuned on them beside the same budget on the scripted demos alone.
    [ -d runs/sim/demos_seen_dart.zarr ] || cp -r runs/sim/demos_seen.zarr runs/sim/demos_seen_dart.zarr
    python -m trainer collect --action-noise 0.3 --episodes 1500 --seed 20000 --workers 2 \
        --out runs/sim/demos_seen_dart.zarr
    finetune gt_dart_8k runs/sim/demos_seen_dart.zarr gt 1 &
    finetune gt_more_8k runs/sim/demos_seen.zarr gt 1
    wait
    for objects in seen unseen; do
        for name in gt_more_8k gt_dart_8k; do
            cell "$name" "runs/student/$name.onnx" none clean "$objects" 180 runs/table2/key
        done
    done
}

looking() {
    # docs/student.md@b8caf57 "The hand strays on the way down": 2000 more scripted demos (seeds 31002..) beside the 1000,
    # the `dart` budget, against gt_more_8k (the object head on recovery frames, run beside it, is retired)
    demos_3k
    finetune gt_3k_8k runs/sim/demos_seen_3k.zarr gt 1
    for objects in seen unseen; do
        WORKERS=1 cell gt_3k_8k runs/student/gt_3k_8k.onnx none clean "$objects" 180 runs/table2/key
    done
}

handpose() {
    # docs/student.md@b8caf57 "The oracle": research/student_v1/oracle.py (60 episodes, execute 8 and 4 of each chunk), then
    # the hand's pose by forward kinematics and the object head's offset from it as state inputs of the GT student,
    # against gt_more_8k (its first try, the `dart` budget from gt_1000_obj1, needed the retired --init that adds
    # state inputs).
    local run exec
    for run in "facts_8k" "hand_8k --hand" "facts_24k --steps 24000" "hand_24k --hand --steps 24000"; do
        set -- $run
        [ -f "runs/student/oracle/$1/oracle.pt" ] || python research/student_v1/oracle.py fit --out "runs/student/oracle/$1" "${@:2}"
        for exec in 8 4; do
            python research/student_v1/oracle.py evaluate "runs/student/oracle/$1/oracle.pt" --episodes 60 --exec "$exec"
        done
    done
    for noise in 0.5 1 1.5 2 3; do  # how precisely perception must place the object
        python research/student_v1/oracle.py evaluate runs/student/oracle/hand_24k/oracle.pt --episodes 60 --exec 4 \
            --facts-noise-cm "$noise"
    done
    # from scratch, as train.sh's GT student at 16000 steps
    python -m trainer student fit --demos runs/sim/demos_seen.zarr --depth-source gt --out runs/student/gt_hpo_16k \
        --object-loss 1 --steps 16000 --batch 32 --lr 3e-4 --warmup 200 --width 16 --head-dims 32 64 128 \
        --threads 1 --ckpt-every 1000 --hand-pose --object-offset
    python -m export runs/student/gt_hpo_16k/ckpt.pt --ddim-steps 4 --out runs/student/gt_hpo_16k.onnx
    export_x4 gt_hpo_16k
    for objects in seen unseen; do
        for name in gt_hpo_16k gt_hpo_16k_x4; do
            cell "$name" "runs/student/$name.onnx" none clean "$objects" 180 runs/table2/key
        done
    done
    python research/student_v1/diagnose.py locate student:runs/student/gt_hpo_16k.onnx \
        --checkpoint runs/student/gt_hpo_16k/ckpt.pt --episodes 30
    # longer training helps the oracle: 8000 more steps from gt_hpo_16k (object loss 1, and 10 to sharpen the
    # object estimate), then 16000 more from the first, three times; options after finetune's own replace them (argparse)
    local hpo="runs/sim/demos_seen.zarr gt 1 --hand-pose --object-offset"
    finetune gt_hpo_more_8k $hpo --init runs/student/gt_hpo_16k/ckpt.pt &
    finetune gt_hpo_obj10_8k $hpo --init runs/student/gt_hpo_16k/ckpt.pt --object-loss 10
    wait
    finetune gt_hpo_more_24k $hpo --init runs/student/gt_hpo_more_8k/ckpt.pt --steps 16000
    finetune gt_hpo_more_40k $hpo --init runs/student/gt_hpo_more_24k/ckpt.pt --steps 16000
    finetune gt_hpo_more_56k $hpo --init runs/student/gt_hpo_more_40k/ckpt.pt --steps 16000
    for name in gt_hpo_more_8k gt_hpo_obj10_8k gt_hpo_more_24k gt_hpo_more_40k gt_hpo_more_56k; do
        export_x4 "$name"
        python research/student_v1/diagnose.py locate "student:runs/student/${name}_x4.onnx" \
            --checkpoint "runs/student/$name/ckpt.pt" --episodes 30
        for objects in seen unseen; do
            cell "${name}_x4" "runs/student/${name}_x4.onnx" none clean "$objects" 180 runs/table2/key
        done
    done
}

probe() {  # name demos [probe options...]: the object estimate of a run (its exec-4 ONNX and checkpoint) on a store
    local name=$1 demos=$2
    shift 2
    python -m trainer student probe --policy "runs/student/${name}_x4.onnx" --demos "$demos" \
        --checkpoint "runs/student/$name/ckpt.pt" "$@"
}

measure() {  # name training-demos [WxH]: a hand-pose student's exec-4 ONNX, its object estimate on 60 held-out demos
    # (at its resolution WxH, default 128x96), on its training demos and on its own episodes (by distance to the
    # object), and its clean cells at 180 episodes
    local name=$1
    heldout_60 "${@:3}"
    export_x4 "$name"
    probe "$name" "runs/student/heldout_60${3:+_$3}.zarr"
    probe "$name" "$2"
    python research/student_v1/diagnose.py locate "student:runs/student/${name}_x4.onnx" \
        --checkpoint "runs/student/$name/ckpt.pt" --episodes 30
    for objects in seen unseen; do
        cell "${name}_x4" "runs/student/${name}_x4.onnx" none clean "$objects" 180 runs/table2/key
    done
}

moredata() {
    # docs/student.md@b8caf57 "The object estimate does not generalise": the handpose recipe (hand pose + object offset)
    # from scratch on the 3000 scripted demos, in one 36000-step cosine schedule, beside the same with the object
    # head's own reading of the object's offset from the hand (--hand-target --seen-offset); one core each
    demos_3k
    local name common="--demos runs/sim/demos_seen_3k.zarr --depth-source gt --object-loss 1 --steps 36000 --batch 32
        --lr 3e-4 --warmup 200 --width 16 --head-dims 32 64 128 --threads 1 --ckpt-every 1000 --hand-pose --object-offset"
    python -m trainer student fit $common --out runs/student/gt3k_hpo_36k &
    python -m trainer student fit $common --hand-target --seen-offset --out runs/student/gt3k_hpos_36k
    wait
    # then 12000 more steps of each (lr 1e-4), as the 1000-demo runs gained from more steps
    local more="runs/sim/demos_seen_3k.zarr gt 1 --hand-pose --object-offset --steps 12000"
    finetune gt3k_hpo_more_12k $more --init runs/student/gt3k_hpo_36k/ckpt.pt &
    finetune gt3k_hpos_more_12k $more --hand-target --seen-offset --init runs/student/gt3k_hpos_36k/ckpt.pt
    wait
    for name in gt3k_hpo_36k gt3k_hpos_36k gt3k_hpo_more_12k gt3k_hpos_more_12k; do
        measure "$name" runs/sim/demos_seen_3k.zarr
    done
}

table() {  # docs/table2.json plus the cells in runs/table2 (rows in the order of STUDENTS, then the reactive one);
           # a cell measured by `key` (180 episodes) replaces the smaller one
    local files=() small
    shopt -s nullglob
    for student in "${STUDENTS[@]}" "reactive_gt"; do
        set -- $student
        files+=(runs/table2/key/"$1"_{clean,stereo}_*_180.json)
        for small in runs/table2/"$1"_{clean,stereo}_*.json; do
            [ -f "runs/table2/key/$(basename "${small%_*}")_180.json" ] || files+=("$small")
        done
    done
    python -m trainer table "${files[@]}" --base docs/table2.json --out docs/table2.json
}

sixk() {
    # docs/student.md@b8caf57 "6000 demos": moredata's --seen-offset student on twice the demos, the same 36000 steps; one
    # run on 2 threads (6000 demos' depth is 12 GB in memory, two runs at once would not fit in 24 GB)
    demos_3k
    grow_demos runs/sim/demos_seen_3k.zarr runs/sim/demos_seen_6k.zarr 6000
    fit gt6k_hpos_36k runs/sim/demos_seen_6k.zarr gt 2 36000 --lr 3e-4 --hand-pose --object-offset --seen-offset
    measure gt6k_hpos_36k runs/sim/demos_seen_6k.zarr
    # then 12000 more steps (lr 1e-4), as moredata's fine-tunes, on 2 threads
    finetune gt6k_hpos_more_12k runs/sim/demos_seen_6k.zarr gt 2 $HPOS --steps 12000 \
        --init runs/student/gt6k_hpos_36k/ckpt.pt
    measure gt6k_hpos_more_12k runs/sim/demos_seen_6k.zarr
}

ddg_depth() {  # model from to [generate options...]: a copy of a demo store with that DDG's depth (DDIM 5) in two
    # 1-core shards; resumable. --replace: the copy drops DDG depth it came with from another generator (train.sh
    # step 3 leaves models/ddg's in demos_seen.zarr), rather than refusing it
    [ -d "$3" ] || cp -r "$2" "$3"
    local pids=() shard
    for shard in 0/2 1/2; do
        python -m trainer ddg generate --demos "$3" --model "$1" --steps 5 --threads 1 --batch 16 --replace \
            --shard "$shard" "${@:4}" &
        pids+=($!)
    done
    for pid in "${pids[@]}"; do wait "$pid"; done
}

ddgb6k() {
    # the paper's point with the best recipe: the best GT student (6000 demos, hand pose, seen offset, 48000
    # steps) fine-tuned 8000 steps (lr 1e-4) on DDG (b)'s depth of the first 1000 of its demos (DDIM 5: 27 min on
    # 2 cores; all 6000 would take ~2.7 h), then its measures and its stereo cells beside the GT student's
    ddg_depth models/ddg_stereo runs/sim/demos_seen.zarr runs/sim/demos_seen_ddg_b.zarr
    finetune ddgb6k_hpos_8k runs/sim/demos_seen_ddg_b.zarr ddg 2 $HPOS --init runs/student/gt6k_hpos_more_12k/ckpt.pt
    measure ddgb6k_hpos_8k runs/sim/demos_seen_ddg_b.zarr
    key ddgb6k_hpos_8k_x4
    # then 12000 more steps (lr 1e-4), as the GT students gained from more steps
    finetune ddgb6k_hpos_more_12k runs/sim/demos_seen_ddg_b.zarr ddg 2 $HPOS --steps 12000 \
        --init runs/student/ddgb6k_hpos_8k/ckpt.pt
    measure ddgb6k_hpos_more_12k runs/sim/demos_seen_ddg_b.zarr
    key ddgb6k_hpos_more_12k_x4
}

ddgb_heldout() {  # the DDG (b) students' object estimate on DDG (b) depth of the 60 held-out demos (and their training demos)
    ddg_depth models/ddg_stereo runs/student/heldout_60.zarr runs/student/heldout_60_ddg_b.zarr
    local name demos
    for name in ddgb6k_hpos_8k ddgb6k_hpos_more_12k; do
        for demos in runs/student/heldout_60_ddg_b.zarr runs/sim/demos_seen_ddg_b.zarr; do
            probe "$name" "$demos" --depth-source ddg
        done
    done
}

ddgb6k_all() {  # next: DDG (b)'s depth of all 6000 demos (~2.7 h on 2 cores), for a fine-tune on all of them
    ddg_depth models/ddg_stereo runs/sim/demos_seen_6k.zarr runs/sim/demos_seen_6k_ddg_b.zarr
}

fine_tunes() {  # prefix demos source threads [fit options...]: `ddgb6k`'s recipe, 8000 steps from the best GT
    # student ($START, default gt6k_hpos_more_12k), then 12000 more, then the exec-4 export
    # runs/student/PREFIX_hpos_more_12k_x4.onnx
    local prefix=$1 demos=$2 source=$3 threads=$4
    shift 4
    finetune "${prefix}_hpos_8k" "$demos" "$source" "$threads" $HPOS "$@" \
        --init "runs/student/${START:-gt6k_hpos_more_12k}/ckpt.pt"
    finetune "${prefix}_hpos_more_12k" "$demos" "$source" "$threads" $HPOS "$@" --steps 12000 \
        --init "runs/student/${prefix}_hpos_8k/ckpt.pt"
    export_x4 "${prefix}_hpos_more_12k"
}

ddgb4k() {
    # `ddgb6k` with 4x the data: the same start, steps and lr on DDG (b) depth of the first 4000 demos of the 6000
    # (`ddgb6k_all` stopped once it had reached them; `--episodes` refuses frames not generated yet)
    local name=ddgb4k_hpos_more_12k
    fine_tunes ddgb4k runs/sim/demos_seen_6k_ddg_b.zarr ddg 2 --episodes 4000
    probe "$name" runs/student/heldout_60_ddg_b.zarr --depth-source ddg
    key "${name}_x4"
}

sensor() {  # [N]
    # docs/student.md@b8caf57 "Trained on the sensor itself": `ddgb6k`'s two fine-tunes (same start, steps, lr) on what the
    # stereo sensor showed at each step of the first N demos (seeds 0..: collect replays demos_seen.zarr's episodes
    # and keeps both depths), a student no generator of this sensor can beat; not a baseline (it trains on the
    # evaluation's sensor), the ceiling of the DDG (b) route
    local n=${1:-1000} demos=runs/sim/demos_seen_stereo.zarr name=sensor_hpos_more_12k
    python -m trainer collect --episodes "$n" --seed 0 --sensor stereo --workers 2 --out $demos
    fine_tunes sensor $demos sensor 2 --episodes "$n"
    python research/student_v1/diagnose.py locate scripted --checkpoint "runs/student/$name/ckpt.pt" --episodes 30 \
        --sensor stereo
    key "${name}_x4"
}

best() {
    # the Table II analogue at the best recipe: `ddgb6k`'s two fine-tunes (same start gt6k_hpos_more_12k, 8000 +
    # 12000 steps, lr 1e-4, the same 1000 demos) on randnoise and on DDG (b) without grafting, one thread each side
    # by side; then the key cells of those, of their GT start (itself and with deploy-time inpainting)
    local run
    for run in "randnoise6k runs/sim/demos_seen.zarr randnoise" "nograftb6k runs/sim/demos_seen_ddg_b.zarr ddg_nograft"; do
        set -- $run
        fine_tunes "$1" "$2" "$3" 1 > "runs/student/$1_hpos.log" 2>&1 &
    done
    wait
    key gt6k_hpos_more_12k_x4 randnoise6k_hpos_more_12k_x4 nograftb6k_hpos_more_12k_x4 gt6k_inpaint_x4
}

ddga6k() {
    # DDG (a), the generator trained on the real captures (models/ddg), at the best recipe: its depth of the same
    # 1000 demos, `ddgb6k`'s two fine-tunes on it, the object estimate on its depth of the 60 held-out demos, key cells
    local name=ddga6k_hpos_more_12k
    ddg_depth models/ddg runs/sim/demos_seen.zarr runs/sim/demos_seen_ddg_a.zarr
    fine_tunes ddga6k runs/sim/demos_seen_ddg_a.zarr ddg 2
    ddg_depth models/ddg runs/student/heldout_60.zarr runs/student/heldout_60_ddg_a.zarr
    probe "$name" runs/student/heldout_60_ddg_a.zarr --depth-source ddg
    key "${name}_x4"
}

nografta6k() {  # `ddga6k`'s fine-tunes on the same store's DDG (a) depth without grafting, and their key cells
    fine_tunes nografta6k runs/sim/demos_seen_ddg_a.zarr ddg_nograft 2
    key nografta6k_hpos_more_12k_x4
}

wrist_measures() {  # name: the exec-4 export of runs/student/NAME, its clean cells, the wrist's turn at the close
    # (diagnose.py turn) and its turn on the held-out demos by step (diagnose.py copycat)
    export_x4 "$1"
    for objects in seen unseen; do
        cell "$1_x4" "runs/student/$1_x4.onnx" none clean "$objects" 180 runs/table2/key
    done
    python research/student_v1/diagnose.py turn "student:runs/student/$1_x4.onnx" --episodes 60 \
        > "runs/table2/turn_$1.log" 2>&1
    python research/student_v1/diagnose.py copycat "runs/student/$1_x4.onnx" --demos runs/student/heldout_60.zarr \
        > "runs/table2/copycat_$1.log" 2>&1
}

wrist() {  # docs/student.md@b8caf57 "The wrist's turn": 1000 demos whose wrist starts anywhere in +-1.5 rad (the default
    # +-0.05 lets the wrist's angle tell a student which way the expert turns it), the best GT student fine-tuned
    # 12000 steps on them
    python -m trainer collect --episodes 1000 --objects seen --seed 50000 --wrist-noise 1.5 --workers 2 \
        --out runs/sim/demos_seen_wrist.zarr
    finetune wrist_hpos_12k runs/sim/demos_seen_wrist.zarr gt 2 $HPOS --steps 12000 \
        --init runs/student/gt6k_hpos_more_12k/ckpt.pt
    wrist_measures wrist_hpos_12k
}

velocity() {  # docs/student.md@b8caf57 "The first step's turn": moredata's gt3k_hpos_36k again (on 2 threads: runs/ had
    # been lost) beside the same student whose denoiser predicts the velocity; who decides the first turn in
    # each denoiser, and wrist_measures with both DDIM spacings. Run in part on 2026-11-25: the fits, decides, both
    # _x4 files' clean cells, gt3k_hpos_v_36k_x4t's seen cell and gt3k_hpos_36k_x4's copycat; not yet the rest
    demos_3k
    local common="--demos runs/sim/demos_seen_3k.zarr --depth-source gt --object-loss 1 --steps 36000 --batch 32
        --lr 3e-4 --warmup 200 --width 16 --head-dims 32 64 128 --threads 2 --ckpt-every 1000 $HPOS"
    python -m trainer student fit $common --out runs/student/gt3k_hpos_36k
    python -m trainer student fit $common --prediction v_prediction --out runs/student/gt3k_hpos_v_36k
    heldout_60
    for name in gt3k_hpos_36k gt3k_hpos_v_36k; do
        python research/student_v1/diagnose.py decides --checkpoint "runs/student/$name/ckpt.pt" \
            --demos runs/sim/demos_seen_3k.zarr --episodes 600 > "runs/table2/decides_$name.log" 2>&1
        wrist_measures "$name"
        python -m export "runs/student/$name/ckpt.pt" --ddim-steps 4 --ddim-spacing trailing --exec-horizon 4 \
            --out "runs/student/${name}_x4t.onnx"
        for objects in seen unseen; do
            cell "${name}_x4t" "runs/student/${name}_x4t.onnx" none clean "$objects" 180 runs/table2/key
        done
        python research/student_v1/diagnose.py copycat "runs/student/${name}_x4t.onnx" \
            --demos runs/student/heldout_60.zarr > "runs/table2/copycat_${name}_x4t.log" 2>&1
    done
}

both_sensors() {  # name: the exec-4 file runs/student/NAME.onnx under stereo, then clean, seen and unseen kinds, 180
    # episodes per cell -> runs/table2/key
    local sensor objects
    for sensor in stereo clean; do
        for objects in seen unseen; do
            cell "$1" "runs/student/$1.onnx" none "$sensor" "$objects" 180 runs/table2/key
        done
    done
}

finer() {  # docs/student.md@b8caf57 "Finer pixels": `velocity`'s velocity student on 3000 demos whose depth is 192x144 of
    # the same 400x300 crop (1.5x finer pixels than 128x96), the same recipe and budget, then `measure` at 192x144
    [ -d runs/sim/demos_seen_3k_192.zarr ] || python -m trainer collect --episodes 3000 --seed 0 --workers 2 \
        --resolution 192x144 --out runs/sim/demos_seen_3k_192.zarr
    python -m trainer student fit --demos runs/sim/demos_seen_3k_192.zarr --depth-source gt --object-loss 1 \
        --steps 36000 --batch 32 --lr 3e-4 --warmup 200 --width 16 --head-dims 32 64 128 --threads 2 \
        --ckpt-every 1000 $HPOS --prediction v_prediction --out runs/student/gt3k192_hpos_v_36k
    measure gt3k192_hpos_v_36k runs/sim/demos_seen_3k_192.zarr 192x144
}

ddga192() {  # [N]: docs/student.md@b8caf57 "DDG (a) at finer pixels": ddga6k's two fine-tunes on DDG (a) depth of the first
    # N (default 1000) demos at 192x144 (the generator runs at its 128x96 and its holes are carried back), from
    # finer's velocity student, then the stereo and clean cells; runs are named ddga192 (N 1000) or ddga192_N
    local n=${1:-1000} prefix=ddga192
    [ "$n" = 1000 ] || prefix=ddga192_$n
    ddg_depth models/ddg runs/sim/demos_seen_3k_192.zarr runs/sim/demos_seen_3k_192_ddg_a.zarr --episodes "$n"
    START=gt3k192_hpos_v_36k fine_tunes "$prefix" runs/sim/demos_seen_3k_192_ddg_a.zarr ddg 2 \
        --prediction v_prediction --episodes "$n"
    both_sensors "${prefix}_hpos_more_12k_x4"
}

ddga192_short() {  # docs/student.md@b8caf57 "A shorter DDG (a) fine-tune": ddga192's first fine-tune alone (8000 steps from
    # finer's student, the 1000 demos), exported exec-4 like the others, under both sensors
    export_x4 ddga192_hpos_8k
    both_sensors ddga192_hpos_8k_x4
}

"${@:?usage: table2.sh train|evaluate|table|key|reactive|dagger|ddg_b|dart|looking|handpose|moredata|sixk|ddgb6k|ddgb_heldout|ddgb6k_all|ddgb4k|sensor|best|ddga6k|nografta6k|wrist|velocity|finer|ddga192|ddga192_short [NAME...]}"
