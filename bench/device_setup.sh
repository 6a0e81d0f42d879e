# Sourced by the device scripts (bench/device_rollout.sh, bench/device_rollout_class.sh) on the lent
# GPU machine, from the repository root, with DATA (the packed scenes), CLASS (the rollout's agent
# class), T0 (the call's start) and L (the log folder) set: installs the wheels the machine's image
# lacks and this checkout, records the machine, starts nvidia-smi dmon; build_cache builds the feature
# cache once, finish sends the checkpoints and logs back (W: the runs' folder).
mkdir -p $L
export PYTHONUNBUFFERED=1 PYTHONPATH=/tmp/site
# the wheels the image lacks, then this checkout in editable mode (the import package maps the
# top-level converters/ and models/ into coster_sumo: run from the tree alone, they are missing)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .device/whl/*.whl \
  > $L/pip.log 2>&1
python3 -m pip install -q --no-index --no-deps --no-build-isolation -e . >> $L/pip.log 2>&1
(nvidia-smi; python3 -c "import torch; print(torch.__version__, torch.cuda.is_available())"; nproc) > $L/machine.txt 2>&1
(nvidia-smi dmon -s u -d 10 > $L/dmon.log 2>&1 &)

build_cache() {  # the feature cache of DATA's split, on every core, before the runs read it
  python3 -c "
from coster_sumo.rollout.train import split_scene_files as s, load_cached_examples as l
from coster_sumo.rollout.config import RolloutConfig as R
t, v = s('$DATA', 0.1, 0)
print(len(t), len(v), [len(l(p, R(agent_class='$CLASS'), 2, None)) for p in (t, v)])" > $L/cache.log 2>&1
  echo "cache ready after $(( $(date +%s) - T0 )) s" >> $L/cache.log
}

finish() {  # TAIL: after the runs: stop dmon, send the checkpoints and logs.tgz back in $OUT
  pkill -f "nvidia-smi dmon" 2>/dev/null
  cp $W/*.json $L/ 2>/dev/null
  cp $W/*.pt "$OUT"/ 2>/dev/null
  tar -czf "$OUT/logs.tgz" -C $W logs
  echo "done after $(( $(date +%s) - T0 )) s"
  ls -la "$OUT"
  tail -n $1 $L/*.log
}
