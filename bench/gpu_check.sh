#!/usr/bin/env bash
# The captured GPU learner's checks, in one go, for a session lent an H100 or H200 (no
# network; `.gpu` from deploy/gpu/pack.sh carried, as for deploy/gpu/check.sh):
#   1. the CUDA tests of the captured update (capture, replay against eager, no host sync
#      on the update path) and of the device module;
#   2. bench/learner_updates.py --device cuda: the ceiling (a TD3 step captured whole)
#      and every algorithm eager and captured, each with its ratio to the ceiling;
#   3. pendulum-td3 end to end, the learner captured on the GPU (learner.compile=auto),
#      14 actors on the machine's cores, one update per env step.
# Figures and logs go to $OUT (default runs/gpu-captured). About 8 minutes.
#
#     deploy/gpu/pack.sh                   # here: the wheels and Ray
#     bash bench/gpu_check.sh              # there, from the repo root
set -uo pipefail
cd "$(dirname "$0")/.."
out=${OUT:-runs/gpu-captured}
mkdir -p "$out"
site=/tmp/graft-site
if [ -d .gpu ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target "$site" .gpu/*.whl || exit 1
  tar xJf .gpu/ray-*.tar.xz -C "$site" || exit 1
fi
export PYTHONPATH="$site:$PWD" PYTHONUNBUFFERED=1 PIP_NO_INDEX=1 PIP_NO_BUILD_ISOLATION=0
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv > "$out/gpu.txt"
python3 -c 'import torch; print("torch", torch.__version__, torch.cuda.get_device_name(0))' \
  >> "$out/gpu.txt" 2>&1

# Runs a named step with a time limit; its whole log goes to $OUT, its end to the screen.
step() {
  local name=$1 limit=$2
  shift 2
  echo "=== $name: $*"
  local start=$SECONDS
  timeout "$limit" "$@" > "$out/$name.log" 2>&1
  echo "=== $name: exit $? after $((SECONDS - start)) s"
  tail -n 25 "$out/$name.log"
}

step tests 180 python3 -m pytest -q -p no:cacheprovider -rs tests/learner/test_captured.py \
  tests/learner/test_device.py -k "cuda or captured"
step learner 200 python3 bench/learner_updates.py --device cuda --compile off,captured \
  --seconds 5 --out "$out"
rm -rf /tmp/graft-gpu-captured  # a machine still warm from an earlier try keeps its folder
step train 240 python3 -m graft.cli train --preset pendulum-td3 --no-progress \
  --actors 14 --env-steps 20000 --set learner.device=cuda --set learner.compile=auto \
  --set eval_every=2000 --run-dir /tmp/graft-gpu-captured
cp /tmp/graft-gpu-captured/summary.json "$out/" 2>/dev/null
python3 - "$out" <<'PY'
import json, sys
s = json.load(open(f"{sys.argv[1]}/summary.json"))
keys = ("learner_device", "learner_compile", "env_steps", "updates", "wall_s",
        "learner_updates_per_s", "learner_wait_fraction", "final_eval_return_mean")
print({k: s.get(k) for k in keys})
PY
