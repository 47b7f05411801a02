#!/usr/bin/env bash
# Wheels for a GPU machine that reaches no package index (run here, where pip works): the
# packages the GPU image lacks, for CPython 3.12 on x86-64 Linux, split into parts of at most
# 56 MiB (a machine receives at most 64 MiB per call, the working tree included), in $1
# (default .gpu, which git ignores).  Send one part per call; checks.sh installs them.
#   benchmarks/gpu/wheels.sh [.gpu]    -> .gpu/part1, .gpu/part2, ...  (see checks.sh)
set -euo pipefail
out=${1:-.gpu}
python=${PYTHON:-.venv/bin/python}
# What `import wirecraft`, MuJoCo Warp and rsl-rl need beyond an image that has torch, numpy,
# matplotlib, pillow, tqdm, absl-py, etils, onnx, onnxscript and tensorboard.
packages=(
  mujoco==4.0.0 mujoco-warp==4.0.0 warp-lang==1.19.0 glfw pyopengl
  gymnasium farama-notifications trimesh manifold3d
  moviepy decorator imageio-ffmpeg proglog python-dotenv
  rsl-rl-lib==5.5.1 tensordict pyvers GitPython gitdb smmap
)
rm -rf "$out" && mkdir -p "$out/wheels"
"$python" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
  --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d "$out/wheels" \
  "${packages[@]}"
# mujoco 4.0 splits into mujoco-core and mujoco-studio: fetch whatever its metadata names.
for wheel in "$out"/wheels/mujoco-4*.whl; do
  for need in $(unzip -p "$wheel" '*/METADATA' | sed -n 's/^Requires-Dist: \(mujoco-[a-z]*\).*/\1/p'); do
    "$python" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
      --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
      --platform manylinux2014_x86_64 -d "$out/wheels" "$need==4.0.0"
  done
done
tar -C "$out" -cf "$out/wheels.tar" wheels
split -b 56m -d -a 1 "$out/wheels.tar" "$out/chunk"
rm -rf "$out/wheels" "$out/wheels.tar"
n=0
for chunk in "$out"/chunk*; do
  n=$((n + 1)); mkdir -p "$out/part$n"; mv "$chunk" "$out/part$n/"
done
du -sh "$out"/part*
echo "$n parts: send part1 ... part$n to the machine (one per call), then run checks.sh there"
