# Sourced by deploy/gpu/check.sh and bench/gpu_check.sh, from the repo root with $out set:
# puts `.gpu`'s wheels and Ray (deploy/gpu/pack.sh) on the path where they were carried,
# records the GPU in $out/gpu.txt, and defines `step NAME LIMIT CMD...`.
mkdir -p "$out"
site=/tmp/graft-site
if [ -d .gpu ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target "$site" .gpu/*.whl || exit 1
  tar xJf .gpu/ray-*.tar.xz -C "$site" || exit 1
fi
export PYTHONPATH="$site:$PWD" PYTHONUNBUFFERED=1
# The tests install the user-task fixture and the examples (`pip install -e`): from the
# image's setuptools, with no index to ask (pip reads PIP_NO_BUILD_ISOLATION=0 as "off").
export PIP_NO_INDEX=1 PIP_NO_BUILD_ISOLATION=0
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv > "$out/gpu.txt"
python3 -c 'import torch; print("torch", torch.__version__, torch.cuda.get_device_name(0))' \
  >> "$out/gpu.txt" 2>&1

# Runs a named step with a time limit; its whole log goes to $out, its end to the screen.
step() {
  local name=$1 limit=$2
  shift 2
  echo "=== $name: $*"
  local start=$SECONDS
  timeout "$limit" "$@" > "$out/$name.log" 2>&1
  echo "=== $name: exit $? after $((SECONDS - start)) s"
  tail -n 25 "$out/$name.log"
}
