#!/usr/bin/env bash
# The GPU check (at most a few minutes on one GPU): every test marked `cuda` (the CUDA paths of k-NN,
# evaluation, localisation, ...), then the per-query timing table at 14k x 4096 on the GPU.
# On a machine without a CUDA device it says so and exits 0 (nothing to check there).
# Usage: bash benchmarks/gpu_check.sh [OUT_DIR]   (OUT_DIR default: gpu_check_out)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-gpu_check_out}"
if ! python -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)" 2>/dev/null; then
    echo "gpu_check: no CUDA device visible to torch here; skipping (run it on a GPU machine)"
    exit 0
fi
mkdir -p "$OUT"
python -c "import torch; print('gpu_check:', torch.cuda.get_device_name(0), 'torch', torch.__version__)" | tee "$OUT/device.txt"
python -m pytest -q -m cuda -p no:cacheprovider 2>&1 | tee "$OUT/tests.txt"
python -m seqnet benchmark timing --device cuda --sizes 14000 --dims 4096 --out "$OUT/timing" 2>&1 | tee "$OUT/timing.txt"
