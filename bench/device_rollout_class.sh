#!/bin/bash
# One prepared call on a lent GPU for a road-user class's rollout (models/rollout_vru.md, "A best-of-K
# term, trained on a lent GPU"), run from the repository root there after
# `python bench/pack_for_device.py CORPUS --agent-class CLASS` here, with `carry: [".device"]`:
#   CLASS=pedestrian bash bench/device_rollout_class.sh      (timeout_s 540)
# Fine-tunes the class's shipped DSA and no-DSA checkpoints side by side on the one GPU, each with
# the plain ELBO and with best-of-K terms of several weights (`train rollout --best-of K
# --best-of-weight W`), all with the same recipe (EPOCHS passes over the packed training examples,
# the learning rate x 0.1 for the last). What comes back in $OUT: the checkpoints and logs.tgz.
# Env: DATA (.device), CLASS, EPOCHS, LR, K, WEIGHTS and NODSA_WEIGHTS (best-of weights besides the
# plain runs; at most 7 runs: $OUT takes 8 files),
# BATCH, THREADS (torch threads per run), DEADLINE (s after start at which every run is stopped).
set -u
T0=$(date +%s)
DATA=${DATA:-.device}
CLASS=${CLASS:-pedestrian}
EPOCHS=${EPOCHS:-6}
LR=${LR:-3e-4}
K=${K:-5}
WEIGHTS=${WEIGHTS:-"0.5 2 8"}
NODSA_WEIGHTS=${NODSA_WEIGHTS:-"0.5 2"}
BATCH=${BATCH:-256}
THREADS=${THREADS:-2}
DEADLINE=${DEADLINE:-470}
END=$((T0 + DEADLINE))
W=/tmp/w; L=/tmp/w/logs
source bench/device_setup.sh
build_cache

run() {  # NAME INIT FLAGS...: the project's command from the class's shipped weights, stopped at the deadline
  local name=$1 init=$2; shift 2
  local left=$((END - $(date +%s)))
  [ $left -gt 5 ] || return 124
  timeout $left python3 -m coster_sumo -q train rollout --data $DATA --agent-class $CLASS --init $init \
    --lr $LR --warmup-steps 100 --epochs $EPOCHS --lr-drop-epoch $EPOCHS --examples-per-epoch 0 \
    --batch-size $BATCH --max-val-examples 500 --seed 0 --threads $THREADS --device cuda --precision bf16 \
    -o $W/$name.pt "$@" > $L/$name.log 2>&1
  echo "== rc=$? after $(( $(date +%s) - T0 )) s" >> $L/$name.log
}

run dsa_plain models/rollout_$CLASS.pt &
for w in $WEIGHTS; do run dsa_bo${K}_w$w models/rollout_$CLASS.pt --best-of $K --best-of-weight $w & done
run nodsa_plain models/rollout_${CLASS}_nodsa.pt --no-dsa &
for w in $NODSA_WEIGHTS; do
  run nodsa_bo${K}_w$w models/rollout_${CLASS}_nodsa.pt --no-dsa --best-of $K --best-of-weight $w &
done
wait
finish 2
