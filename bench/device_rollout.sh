#!/bin/bash
# One prepared call on a lent GPU (models/rollout.md, "Training on a lent GPU"), run from the
# repository root there after `python bench/pack_for_device.py CORPUS` here, with `carry: [".device"]`:
#   DEADLINE=470 bash bench/device_rollout.sh      (timeout_s 540)
# Four CVAE runs side by side on the one GPU (DSA and no DSA from fresh weights; both shipped
# checkpoints fine-tuned), each first for one epoch, whose time sets how many epochs fit before the
# deadline and where the learning rate drops, then resumed to that count. If CUDA fails, a run falls
# back to float32 there, then to the CPU. The GPU tests run beside the cache build. What comes back
# in $OUT: the four checkpoints and logs.tgz (metrics, logs, GPU tests, nvidia-smi, dmon).
# Env: DATA (.device), DEVICE (cuda), EPE (examples per epoch), BATCH, DEADLINE (s after start),
# THREADS (torch threads per run), EXTRA (flags for every run), CPU_PREC (the CPU fallback's).
set -u
T0=$(date +%s)
DATA=${DATA:-.device}
DEVICE=${DEVICE:-cuda}
EPE=${EPE:-200000}
BATCH=${BATCH:-1024}
DEADLINE=${DEADLINE:-470}
THREADS=${THREADS:-3}
EXTRA=${EXTRA:-}
END=$((T0 + DEADLINE))
W=/tmp/w; L=/tmp/w/logs; CLASS=vehicle
source bench/device_setup.sh
(timeout 200 python3 -m pytest -q -p no:cacheprovider -m gpu tests/rollout/test_rollout_cli.py tests/prior/test_prior.py \
  > $L/pytest_gpu.log 2>&1; echo "rc=$?" >> $L/pytest_gpu.log) &
build_cache

train() {  # NAME FLAGS... : the project's command, stopped at the deadline
  local name=$1; shift
  local left=$((END - $(date +%s)))
  [ $left -gt 5 ] || return 124
  timeout $left python3 -m coster_sumo -q train rollout --data $DATA --batch-size $BATCH \
    --examples-per-epoch $EPE --threads $THREADS $EXTRA -o $W/$name.pt "$@" >> $L/$name.log 2>&1
}

one() {  # NAME DROP_FRACTION FLAGS...
  local name=$1 frac=$2; shift 2
  local flags="" rc
  for f in "--device $DEVICE --precision bf16" "--device $DEVICE --precision fp32" "--device cpu --precision ${CPU_PREC:-bf16}"; do
    echo "== epoch 1 with $f ($(( $(date +%s) - T0 )) s)" >> $L/$name.log
    train $name $f --epochs 1 "$@"; rc=$?
    [ $rc -eq 0 ] && { flags=$f; break; }
    [ $rc -eq 124 ] && return
    rm -f $W/$name.pt.state
  done
  [ -n "$flags" ] || return
  local plan
  plan=$(python3 -c "
import json, time
t1 = json.load(open('$W/$name.json'))['epochs'][0]['time_s']
left = $END - time.time() - 25
more = int(left * 0.95 // t1)
e = 1 + max(more, 0)
d = max(2, round($frac * e)) if e >= 3 else 0
print(e, d, round(t1, 1))")
  set -- $plan "$@"
  local e=$1 d=$2 t1=$3; shift 3
  echo "== epoch 1 took $t1 s; going on to $e epochs, lr drop at $d ($(( $(date +%s) - T0 )) s)" >> $L/$name.log
  [ $e -gt 1 ] || return
  train $name $flags --epochs $e --lr-drop-epoch $d "$@"
  echo "== stopped with rc=$? after $(( $(date +%s) - T0 )) s" >> $L/$name.log
}

one dsa 0.8 --lr 2e-3 --warmup-steps 300 --seed 0 &
one nodsa 0.8 --no-dsa --lr 2e-3 --warmup-steps 300 --seed 0 &
one dsa_ft 0.7 --init models/rollout.pt --lr 4e-4 --warmup-steps 100 --seed 1 &
one nodsa_ft 0.7 --no-dsa --init models/rollout_nodsa.pt --lr 4e-4 --warmup-steps 100 --seed 1 &
wait
finish 3
