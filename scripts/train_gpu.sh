#!/usr/bin/env bash
# Train the shipped models of several classes at once on one CUDA GPU (how the GPU-trained
# shipped models were made; docs/models.md). Each class samples its procedural training set on
# a share of the CPU cores, then trains under torchrun on the GPU; the classes share the GPU.
#
#   [ARCH=NAME] scripts/train_gpu.sh OUT_DIR SHAPES STEPS CLASS [CLASS ...]
#
# ARCH: the decoder architecture (`jsrte train --arch`; default cpu, the shipped models' network).
# Writes OUT_DIR/<class>/ (run folder: model.safetensors, train_log.csv, train_state, data/).
# Runs where `python3 -m jsrte.cli` works (an installed jsrte, or PYTHONPATH=src with its
# dependencies). Batch: 32 shapes x 4096 points per step (DeepSDF's size is 64 x 16384).
set -euo pipefail
out=$1 shapes=$2 steps=$3
shift 3
classes=("$@")
cores=$(nproc)
threads=$(( cores / ${#classes[@]} > 0 ? cores / ${#classes[@]} : 1 ))
export TORCH_ALLOW_TF32_CUBLAS_OVERRIDE=1   # TF32 matrix products: ~4x faster training on Ampere+
mkdir -p "$out"
pids=()
for c in "${classes[@]}"; do
  python3 -m torch.distributed.run --standalone --nproc_per_node=1 -m jsrte.cli train \
    --category "$c" --name "$c" --arch "${ARCH:-cpu}" --shapes "$shapes" --steps "$steps" --batch-shapes 32 --points 4096 \
    --checkpoint-every 500 --threads "$threads" --no-progress --out "$out/$c" >"$out/$c.log" 2>&1 &
  pids+=($!)
done
status=0
for i in "${!pids[@]}"; do
  wait "${pids[$i]}" || { echo "training ${classes[$i]} failed:"; tail -5 "$out/${classes[$i]}.log"; status=1; }
done
exit $status
