#!/usr/bin/env bash
# Run HERE (the CPU machine), once per session, before benchmarks/device_check.sh goes to a lent GPU
# machine. That machine is bare apart from its own PyTorch (Python 3.12) and sees neither PyPI nor
# ../shared, so this puts what the check needs inside the checkout, in folders git ignores:
#   .whl/         wheels of the runtime dependencies the GPU image lacks (cholespy, trimesh,
#                 fast-simplification, tqdm) for CPython 3.12 on x86-64 manylinux
#   .psb_subset/  55 PSB meshes (the first three of each category, and mesh 114, which no shift
#                 factors decimated) and their human labels
# Then call the device tool with carry [".whl", ".psb_subset"], timeout_s 540 and the command
#   bash benchmarks/device_check.sh
# (about 21 MB travels: 6.5 MB of wheels, about 14 MB of meshes).
set -euo pipefail
cd "$(dirname "$0")/.."
# git ignores both (in a worktree too: --git-path finds the repository's own exclude file).
exclude=$(git rev-parse --git-path info/exclude)
mkdir -p "$(dirname "$exclude")"
for d in .whl .psb_subset; do grep -qxF "/$d/" "$exclude" 2>/dev/null || echo "/$d/" >> "$exclude"; done
mkdir -p .whl
for spec in cholespy fast-simplification trimesh tqdm; do
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform any -d .whl "$spec"
done
psb=${TORCHAKVF_PSB:-../shared/psb}
rm -rf .psb_subset && mkdir -p .psb_subset/meshes .psb_subset/gt
ids=""
for c in $(seq 0 18); do
  [ "$c" = 13 ] && continue                      # Spring (261-280) is not in the benchmark
  for i in 1 2 3; do
    ids="$ids $((c * 20 + i))"
  done
done
for id in $ids 114; do
  [ -f "$psb/meshes/$id.off.gz" ] || continue
  cp "$psb/meshes/$id.off.gz" .psb_subset/meshes/
  [ -d "$psb/gt/$id" ] && cp -r "$psb/gt/$id" .psb_subset/gt/
done
cp "$psb/README.md" .psb_subset/ 2>/dev/null || true
du -sh .whl .psb_subset
