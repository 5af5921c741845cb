#!/usr/bin/env bash
# Packs, here, what a GPU machine without network needs to run graft (deploy/gpu/check.sh):
# Python 3.12 wheels of the packages its image lacks, and Ray as a tarball (its wheel is
# 79 MB; without its Java jars, RLlib, Serve, Data, Train, Tune, LLM and the dashboard's web
# page, 28 MB xz). The machine's image brings torch with CUDA, numpy, grpcio's peers,
# matplotlib, tensorboard and pytest (/work/.library/device/KINDS.md lists them).
#
#     deploy/gpu/pack.sh [FOLDER]     # default .gpu (git-ignored), 35 MB in all
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:-.gpu}
mkdir -p "$out"
ray_version=$(.venv/bin/python -c 'import ray; print(ray.__version__)')
grpc_version=$(.venv/bin/python -c 'import grpc; print(grpc.__version__)')
health_version=$(.venv/bin/python -c 'from importlib.metadata import version; print(version("grpcio-health-checking"))')
wheels=(
  gymnasium farama-notifications py_trees pydot jsonschema jsonschema-specifications
  referencing rpds-py "grpcio==$grpc_version" "grpcio-health-checking==$health_version"
  "protobuf>=7.35.1,<8"
)
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
  --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
  --platform manylinux2014_x86_64 -d "$out" "${wheels[@]}"
if [ ! -f "$out/ray-$ray_version.tar.xz" ]; then
  work=$(mktemp -d)
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
    --implementation cp --platform manylinux2014_x86_64 -d "$work" "ray==$ray_version"
  (cd "$work" && unzip -q ray-*.whl && rm ray-*.whl \
    && rm -rf ray/jars ray/rllib ray/data ray/serve ray/train ray/tune ray/llm \
              ray/dashboard/client/build \
    && tar cf - ray ray-*.dist-info | xz -T2 -6 > ray.tar.xz)
  mv "$work/ray.tar.xz" "$out/ray-$ray_version.tar.xz"
  rm -rf "$work"
fi
du -sh "$out"
