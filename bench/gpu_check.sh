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
source deploy/gpu/prelude.sh

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
