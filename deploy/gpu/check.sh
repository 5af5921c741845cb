#!/usr/bin/env bash
# The GPU checks of graft, in one go, on a machine with CUDA and no network (the device
# tool's H200, with `.gpu` from deploy/gpu/pack.sh carried): the CUDA tests,
# bench/learner_updates.py on the GPU (eager, compiled, CUDA graphs) and a short pendulum-td3 with
# `learner.device=cuda`. Figures and logs go to $OUT (default runs/gpu), 8 files at most.
#
#     deploy/gpu/pack.sh                   # here: the wheels and Ray (35 MB)
#     bash deploy/gpu/check.sh             # there, from the repo root (about 6 minutes)
set -uo pipefail
cd "$(dirname "$0")/../.."
out=${OUT:-runs/gpu}
mkdir -p "$out"
site=/tmp/graft-site
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target "$site" .gpu/*.whl || exit 1
tar xJf .gpu/ray-*.tar.xz -C "$site" || exit 1
export PYTHONPATH="$site:$PWD" PYTHONUNBUFFERED=1
# The tests install the user-task fixture and the examples (`pip install -e`): from the
# image's setuptools, with no index to ask (pip reads PIP_NO_BUILD_ISOLATION=0 as "off").
export PIP_NO_INDEX=1 PIP_NO_BUILD_ISOLATION=0
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
  tail -n 20 "$out/$name.log"
}

# Every device test (CUDA ones included), then the presets' smoke runs that record it.
step tests 150 python3 -m pytest -q -p no:cacheprovider -n 8 tests/learner/test_device.py \
  "tests/graft/test_presets_smoke.py::test_preset_runs_through_the_service"
step learner 200 python3 bench/learner_updates.py --device cuda --compile off,compile,cuda_graphs \
  --compiled-learners td3 --seconds 5 --out "$out"
rm -rf /tmp/graft-gpu-run  # a machine still warm from an earlier try keeps its folder
step train 240 python3 -m graft.cli train --preset pendulum-td3 --no-progress \
  --env-steps 20000 --set learner.device=cuda --set prefetch=16 --set eval_every=2000 \
  --run-dir /tmp/graft-gpu-run
cp /tmp/graft-gpu-run/summary.json /tmp/graft-gpu-run/learning_curve.png "$out/" 2>/dev/null
python3 - "$out" <<'PY'
import json, sys
s = json.load(open(f"{sys.argv[1]}/summary.json"))
keys = ("learner_device", "env_steps", "updates", "wall_s", "learner_updates_per_s",
        "learner_wait_fraction", "final_eval_return_mean")
print({k: s.get(k) for k in keys})
PY
