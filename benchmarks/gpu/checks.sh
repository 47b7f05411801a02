#!/usr/bin/env bash
# The GPU figures of the MuJoCo Warp backend, on a machine with a CUDA GPU:
#   benchmarks/gpu/checks.sh OUT DEVICE [tests] [bench] [parity] [train]   (default: all four)
# OUT: folder for logs and JSON; DEVICE: the Warp device (cuda:0).  Sizes come from the
# environment: COUNTS (bench, default 1024,4096,8192,16384,32768), FLEX_COUNTS (rod and FEM,
# default 2048,8192), ROW_SECONDS (default 60) and WARMUP (default 5): the reference's protocol;
# PARITY_EPISODES (per seed, 4 seeds; default 16); TRAIN_ENVS (default 4096), TRAIN_STEPS
# (default 2e6).
# Wheels: where the machine reaches no package index, benchmarks/gpu/wheels.sh made
# .gpu/part1 ... .gpu/partN here; this script installs them to /tmp/site first.
set -uo pipefail
out=${1:?usage: checks.sh OUT DEVICE [tests] [bench] [parity] [train]}
device=${2:?usage: checks.sh OUT DEVICE [tests] [bench] [parity] [train]}
shift 2
parts=${*:-tests bench parity train}
mkdir -p "$out"
py=${PYTHON:-python3}
export PYTHONUNBUFFERED=1 MUJOCO_GL=${MUJOCO_GL:-egl}
if compgen -G ".gpu/part*/chunk*" >/dev/null; then
  rm -rf /tmp/wheels && cat .gpu/part*/chunk* | tar -x -C /tmp \
    && "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
      --target /tmp/site /tmp/wheels/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD/src
else
  export PYTHONPATH=$PWD/src${PYTHONPATH:+:$PYTHONPATH}
fi
wirecraft() { "$py" -c 'import sys; from wirecraft.cli import main; sys.exit(main())' "$@"; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$out/gpu.txt"
"$py" -c "import mujoco, mujoco_warp, warp; print('mujoco', mujoco.__version__, 'warp', warp.__version__)" \
  | tee -a "$out/gpu.txt" || exit 1
status=0
for part in $parts; do
  start=$(date +%s)
  case $part in
    tests)  # the CPU-device parity tests, on the GPU
      WIRECRAFT_TEST_WARP_DEVICE=$device "$py" -m pytest -q -p no:cacheprovider \
        tests/test_warp_backend.py 2>&1 | tee "$out/tests.log" ;;
    bench)  # throughput sweep to the largest count that fits, then the flex wires
      wirecraft bench --suite envs --backend warp --device "$device" --task insertion \
        --num-envs "${COUNTS:-1024,4096,8192,16384,32768}" --seconds "${ROW_SECONDS:-60}" \
        --warmup "${WARMUP:-5}" --out "$out/bench" --json "$out/bench.json" 2>&1 \
        | tee "$out/bench.log"
      wirecraft bench --suite envs --backend warp --device "$device" --task insertion \
        --wire rod fem --num-envs "${FLEX_COUNTS:-2048,8192}" --seconds "${ROW_SECONDS:-60}" \
        --warmup "${WARMUP:-5}" --out "$out/bench_flex" --json "$out/bench_flex.json" 2>&1 \
        | tee "$out/bench_flex.log" ;;
    parity)  # the scripted experts' success on both backends, same seeds
      "$py" benchmarks/bench_warp_parity.py --device "$device" --seeds 4 \
        --episodes "${PARITY_EPISODES:-16}" --batch 64 --quiet --json "$out/parity.json" 2>&1 \
        | tee "$out/parity.log" ;;
    train)  # state PPO with the physics on the GPU, end to end
      rm -rf /tmp/ppo_warp
      wirecraft train ppo --task insertion --backend warp --warp-device "$device" \
        --num-envs "${TRAIN_ENVS:-4096}" --steps "${TRAIN_STEPS:-2e6}" --set num_steps_per_env=32 \
        --out /tmp/ppo_warp --json "$out/train.json" 2>&1 | tail -40 > "$out/train.log" ;;
    *) echo "unknown part $part (tests, bench, parity, train)"; exit 2 ;;
  esac
  code=${PIPESTATUS[0]}
  [ "$code" = 0 ] || status=$code
  echo "$part: exit $code in $(( $(date +%s) - start )) s" | tee -a "$out/parts.txt"
done
exit $status
