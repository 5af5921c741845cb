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
source deploy/gpu/prelude.sh

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
