#!/usr/bin/env bash
# The GPU check (at most 8 minutes on one GPU): every test marked `cuda` (the CUDA paths of k-NN,
# evaluation, localisation in float32 and half precision, training, maps, an NCCL process group), then
# the per-query timing table at 14k x 4096 on the GPU, printed beside the paper's GTX 1080 Ti row.
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
status=0
timeout 240 python -m pytest -q -m cuda -p no:cacheprovider 2>&1 | tee "$OUT/tests.txt" || status=1
timeout 240 python -m seqnet benchmark timing --device cuda --sizes 14000 --dims 4096 --out "$OUT/timing" 2>&1 \
    | tee "$OUT/timing.txt" || status=1
echo "gpu_check: done (status $status); results in $OUT"
exit $status
