#!/usr/bin/env bash
# The GPU check, run ON a lent GPU machine by the device tool, in under 8 minutes:
#   1. the CUDA tests (pytest -m cuda: each stage on CUDA against the CPU result),
#   2. a bench subset on CUDA and on CPU in the same run (34 PSB meshes, every protocol k),
# and writes the figures under $OUT (what comes back) as device_check.md plus the raw reports.
# Prepare its inputs here first: bash benchmarks/device_prepare.sh (see there), then run this with
# carry [".whl", ".psb_subset"]. Commit what comes back to benchmarks/results/.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/device}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
if compgen -G ".whl/*.whl" > /dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "wheel install failed"; exit 1; }
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
psb=${TORCHAKVF_PSB:-.psb_subset}
export TORCHAKVF_PSB=$psb
{
  echo "# Device check, $(date -u +%Y-%m-%dT%H:%MZ)"
  echo
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null | sed 's/^/- GPU: /'
  python3 -c "import torch, sys; print(f'- torch {torch.__version__}, CUDA {torch.version.cuda}, Python {sys.version.split()[0]}')"
  echo
} > "$OUT/device_check.md"

echo "== CUDA tests"
timeout 240 python3 -m pytest -q -m cuda -p no:cacheprovider tests 2>&1 | tee "$OUT/pytest_cuda.log"
rc_tests=${PIPESTATUS[0]}
{ echo "## CUDA tests (pytest -m cuda, exit $rc_tests)"; echo; echo '```'; tail -n 15 "$OUT/pytest_cuda.log"; echo '```'; echo; } >> "$OUT/device_check.md"

for dev in cuda cpu; do
  echo "== bench on $dev"
  timeout 150 python3 -m torchakvf.cli bench --psb "$psb" --device "$dev" --out "/tmp/bench_$dev" \
      --baseline-every 0 2>&1 | tail -n 5
  if [ -f "/tmp/bench_$dev/report.md" ]; then
    cp "/tmp/bench_$dev/report.json" "$OUT/bench_${dev}.json"
    { echo "## bench on $dev"; echo; sed -n '1,60p' "/tmp/bench_$dev/report.md"; echo; } >> "$OUT/device_check.md"
  else
    echo "## bench on $dev: no report (timed out or failed)" >> "$OUT/device_check.md"
  fi
done
python3 - "$OUT" <<'PY' >> "$OUT/device_check.md"
import json, sys, pathlib
out = pathlib.Path(sys.argv[1])
runs = {}
for dev in ("cuda", "cpu"):
    p = out / f"bench_{dev}.json"
    if p.is_file():
        runs[dev] = json.loads(p.read_text())["runs"]["batched"]
if len(runs) == 2:
    w = {d: r["wall_seconds"] for d, r in runs.items()}
    print(f"## CUDA against CPU, same meshes, same run\n\nwall: cuda {w['cuda']:.1f} s, cpu {w['cpu']:.1f} s, "
          f"ratio {w['cpu'] / w['cuda']:.2f}x\n")
PY
cat "$OUT/device_check.md"
exit "$rc_tests"
