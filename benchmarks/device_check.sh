#!/usr/bin/env bash
# The device check, run ON a lent GPU machine by the device tool, in under 8 minutes (all steps
# together are capped at CHECK_SECONDS, default 420 s):
#   0. environment: GPU, torch, the carried wheels importable, one CHOLMOD solve on CUDA;
#   1. the CUDA tests: pytest -m cuda (tests/test_cuda.py and the other tests that take the cuda
#      fixture), at most 120 s;
#   2. the batched evaluation (benchmarks/device_eval.py): every mesh of the PSB subset (the
#      first three of each category and mesh 114: 55 meshes) through `eval --batched` on the
#      device, host workers feeding the solving process: per-stage host and device seconds, the
#      share of wall time the solving process waited for host work, synchronizations counted in
#      CUDA's sync debug mode, peak reserved memory, failures, 1-RI; then RATIO_MESHES (8)
#      meshes, 114 among them, batched and one mesh per batch in the same process: the
#      one-at-a-time / batched ratio;
# and writes ONE results file, $OUT/device_check.md (default OUT benchmarks/results/device; the
# logs beside it).
#
# Before: bash benchmarks/device_prepare.sh here (wheels + PSB subset, git-ignored), then call the
# device tool with carry [".whl", ".psb_subset"], timeout_s 540 and the command
#   bash benchmarks/device_check.sh
# Commit what comes back (device_check.md) as benchmarks/results/device_check.md.
#
# DEVICE=cpu runs the same check on the CPU (no CUDA tests; syncs and reserved memory "n/a"),
# e.g. on a few meshes to try the script where no GPU is lent:
#   DEVICE=cpu IDS=61,114 COARSE_FACES=600 N_FIELDS=8 RATIO_MESHES=2 WORKERS=2 EVAL_SECONDS=900 \
#     CHECK_SECONDS=1000 bash benchmarks/device_check.sh
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/device}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
deadline=$((SECONDS + ${CHECK_SECONDS:-420}))
left() { echo $((deadline - SECONDS)); }
cap() { local l; l=$(left); [ "$l" -lt "$1" ] && echo "$l" || echo "$1"; }   # min(cap, time left)
device=${DEVICE:-cuda}
md="$OUT/device_check.md"

# The carried wheels, where this Python lacks the runtime dependencies (the GPU image does).
if ! python3 -c "import cholespy, trimesh, fast_simplification" 2>/dev/null && compgen -G ".whl/*.whl" > /dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "wheel install failed"; exit 1; }
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
psb=${TORCHAKVF_PSB:-.psb_subset}
[ -d "$psb/meshes" ] || psb=../shared/psb
export TORCHAKVF_PSB=$psb

# ---- 0. environment -------------------------------------------------------------------------
{
  echo "# Device check, $(date -u +%Y-%m-%dT%H:%MZ)"
  echo
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null | sed 's/^/- GPU: /'
  python3 - <<'PY' 2>&1
import sys
import torch
print(f"- torch {torch.__version__}, CUDA {torch.version.cuda}, Python {sys.version.split()[0]}, "
      f"{torch.get_num_threads()} threads; torch.cuda.is_available() = {torch.cuda.is_available()}")
try:
    import cholespy, fast_simplification, trimesh  # noqa: F401
    print(f"- cholespy, fast_simplification, trimesh {trimesh.__version__} import")
except Exception as exc:  # noqa: BLE001
    print(f"- IMPORT FAILED: {type(exc).__name__}: {exc}")
if torch.cuda.is_available():
    try:   # one CHOLMOD factor + solve on the GPU: the path LOBPCG's preconditioner takes there
        from torchakvf.solvers.factor import ShiftedFactor
        n = 50
        i = torch.arange(n, device="cuda")
        rows, cols = torch.cat([i, i[1:], i[:-1]]), torch.cat([i, i[:-1], i[1:]])
        vals = torch.cat([torch.full((n,), 2.0), torch.full((2 * n - 2,), -1.0)]).double().cuda()
        f = ShiftedFactor(rows, cols, vals, torch.ones(n, dtype=torch.float64, device="cuda"))
        x = f.solve(torch.ones(n, 3, dtype=torch.float64, device="cuda"))
        print(f"- CHOLMOD on CUDA: solve ok (sigma {f.sigma}, x on {x.device}, finite {bool(x.isfinite().all())})")
    except Exception as exc:  # noqa: BLE001
        print(f"- CHOLMOD on CUDA FAILED: {type(exc).__name__}: {exc}")
PY
  echo "- PSB: $psb ($(ls "$psb/meshes" 2>/dev/null | wc -l) meshes); device $device; ids ${IDS:-all}"
  echo
} > "$md"
cat "$md"
has_cuda=$(python3 -c "import torch; print(int(torch.cuda.is_available()))" 2>/dev/null || echo 0)

# ---- 1. CUDA tests --------------------------------------------------------------------------
rc_tests=0
if [ "$device" = cuda ]; then
  echo "== CUDA tests (at most $(cap 120) s)"
  timeout "$(cap 120)" python3 -m pytest -q -ra -m cuda -p no:cacheprovider tests 2>&1 | tee "$OUT/pytest_cuda.log"
  rc_tests=${PIPESTATUS[0]}
  [ "$rc_tests" = 124 ] && echo "TIMED OUT" >> "$OUT/pytest_cuda.log"
  { echo "## CUDA tests (pytest -m cuda, exit $rc_tests)"; echo; echo '```'; tail -n 25 "$OUT/pytest_cuda.log"; echo '```'; echo; } >> "$md"
fi
if [ "$device" = cuda ] && [ "$has_cuda" != 1 ]; then
  echo "## batched eval on cuda: no CUDA on this machine; not run (DEVICE=cpu runs it on the CPU)" >> "$md"
  cat "$md"; exit 1
fi

# ---- 2. the batched evaluation ------------------------------------------------------------------
t=$(cap "${EVAL_SECONDS:-330}")
echo "== batched eval on $device (at most $t s)"
timeout "$t" python3 benchmarks/device_eval.py --psb "$psb" --device "$device" --out "$OUT/device_eval.json" \
    ${IDS:+--ids "$IDS"} --ratio-meshes "${RATIO_MESHES:-8}" --coarse-faces "${COARSE_FACES:-4000}" \
    ${N_FIELDS:+--n-fields "$N_FIELDS"} ${WORKERS:+--workers "$WORKERS"} > "$OUT/device_eval.log" 2>&1
rc=$?
tail -n 4 "$OUT/device_eval.log"
python3 - "$OUT/device_eval.json" "$rc" <<'PY' >> "$md"
import json, pathlib, sys
path, rc = pathlib.Path(sys.argv[1]), sys.argv[2]
print(f"## Batched eval (benchmarks/device_eval.py, exit {rc}; 124 = timed out)\n")
if not path.is_file():
    print("no figures written"); sys.exit()
f = json.loads(path.read_text())
def line(name, r):
    t = r.get("timings") or {}
    peak = r["peak_reserved_mib"]
    peak = peak if isinstance(peak, str) else f"{peak:.0f} MiB"
    waited = t.get("wait_prepare", 0) + t.get("wait_cut", 0)
    print(f"- {name}: {r['meshes'] - r['failed']}/{r['meshes']} meshes in {r['wall_seconds']:.1f} s, "
          f"1-RI {r['rand_index_error']:.4f}; solving process: pack {t.get('pack', 0):.1f} s, "
          f"akvf {t.get('akvf', 0):.1f} s, rounds {t.get('rounds', 0):.1f} s, on or waiting for host "
          f"work {waited:.1f} s ({100 * t.get('host_share', 0):.0f}%); host workers ({t.get('workers')}): "
          f"prepare {t.get('prepare', 0):.1f} s, cut {t.get('cut', 0):.1f} s, score {t.get('score', 0):.1f} s; "
          f"{t.get('batches')} batches, {t.get('bisections')} bisected; syncs {r['syncs']}; peak reserved {peak}")
if "eval" in f:
    line(f"eval of {len(f['ids'])} meshes", f["eval"])
if "ratio" in f:
    r = f["ratio"]
    line(f"batched, meshes {f['ratio_ids']}", r["batched"])
    line("one mesh per batch, same meshes", r["one_at_a_time"])
    print(f"- one at a time / batched: {r['one_at_a_time_over_batched']:.2f}x (> 1: batching is faster)")
print("\n```json\n" + json.dumps(f, indent=1) + "\n```")
PY
echo "- check took $SECONDS s" >> "$md"
sed -n '/^## Batched eval/,$p' "$md" | head -n 8
[ "$rc_tests" = 0 ] && exit "$rc" || exit "$rc_tests"
