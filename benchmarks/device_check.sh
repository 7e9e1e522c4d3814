#!/usr/bin/env bash
# The GPU check, run ON a lent GPU machine by the device tool, in under 8 minutes (all steps
# together are capped at CHECK_SECONDS, default 420 s):
#   0. environment: GPU, torch, the carried wheels importable, one CHOLMOD solve on CUDA;
#   1. the CUDA tests: pytest -m cuda (tests/test_cuda.py: every stage on CUDA against the CPU
#      result; the other tests that take the cuda fixture);
#   2. a bench subset on CUDA, then the same on CPU: the first BENCH_LIMIT (6) meshes of the PSB
#      subset in BENCH_CATEGORIES (Cup, Glasses, Airplane: ids 21, 22, 41, 42, 61, 62, ~4000 faces
#      each once decimated; Human's 9-10 k's per mesh took 2 minutes for 2 meshes on the shared
#      CPU machine) at every protocol k,
#      batched at the device's default budget, and "batched vs one at a time" at the face
#      budgets BENCH_BUDGETS (8000, 24000: 2 and all 6 meshes a batch; torchakvf bench --budgets),
#      same meshes, same run;
#   2b. full-resolution ta.akvf on CUDA (PSB 21 and 301) against scipy eigsh on the CPU, wall
#      clock (benchmarks/akvf_fullres.py --device cuda), at most 75 s;
# and writes the figures under $OUT (what comes back; default benchmarks/results/device):
# device_check.md (everything), pytest_cuda.log, bench_{cuda,cpu}.json and .log,
# akvf_fullres_cuda.md and .log.
#
# Before: bash benchmarks/device_prepare.sh here (wheels + PSB subset, git-ignored), then call the
# device tool with carry [".whl", ".psb_subset"], timeout_s 540 and the command
#   bash benchmarks/device_check.sh
# Commit what comes back (device_check.md) as benchmarks/results/device_check.md, the one current
# GPU figure (benchmarks/README.md cites it). On a machine without CUDA (a dry run) the CUDA tests skip and the CUDA bench
# reports "no CUDA"; BENCH_LIMIT=4 keeps such a run short.
set -uo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-benchmarks/results/device}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
deadline=$((SECONDS + ${CHECK_SECONDS:-420}))
left() { echo $((deadline - SECONDS)); }
cap() { local l; l=$(left); [ "$l" -lt "$1" ] && echo "$l" || echo "$1"; }   # min(cap, time left)
limit=${BENCH_LIMIT:-6}
categories=${BENCH_CATEGORIES:-Cup,Glasses,Airplane}
budgets=${BENCH_BUDGETS:-8000,24000}
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
  echo "- PSB: $psb ($(ls "$psb/meshes" 2>/dev/null | wc -l) meshes); bench: first $limit meshes of $categories, budgets $budgets"
  echo
} > "$md"
cat "$md"
has_cuda=$(python3 -c "import torch; print(int(torch.cuda.is_available()))" 2>/dev/null || echo 0)

# ---- 1. CUDA tests --------------------------------------------------------------------------
echo "== CUDA tests (at most $(cap 150) s)"
timeout "$(cap 150)" python3 -m pytest -q -ra -m cuda -p no:cacheprovider tests 2>&1 | tee "$OUT/pytest_cuda.log"
rc_tests=${PIPESTATUS[0]}
[ "$rc_tests" = 124 ] && echo "TIMED OUT" >> "$OUT/pytest_cuda.log"
{ echo "## CUDA tests (pytest -m cuda, exit $rc_tests)"; echo; echo '```'; tail -n 25 "$OUT/pytest_cuda.log"; echo '```'; echo; } >> "$md"

# ---- 2. bench subset, CUDA then CPU -----------------------------------------------------------
for dev in cuda cpu; do
  if [ "$dev" = cuda ] && [ "$has_cuda" != 1 ]; then
    echo "## bench on cuda: no CUDA on this machine (torch.cuda.is_available() is False); not run" >> "$md"
    echo >> "$md"
    continue
  fi
  t=$(cap $([ "$dev" = cuda ] && echo 150 || echo 120))
  if [ "$t" -lt 20 ]; then
    echo "## bench on $dev: not run (check time used up)" >> "$md"; continue
  fi
  echo "== bench on $dev (at most $t s)"
  rm -rf "/tmp/bench_$dev"
  timeout "$t" python3 -m torchakvf.cli bench --psb "$psb" --device "$dev" --out "/tmp/bench_$dev" \
      --limit "$limit" --categories "$categories" --baseline-every 0 --budgets "$budgets" \
      > "$OUT/bench_$dev.log" 2>&1
  rc=$?
  tail -n 6 "$OUT/bench_$dev.log"
  if [ -f "/tmp/bench_$dev/report.md" ]; then   # partial when the bench hit its time limit
    cp "/tmp/bench_$dev/report.json" "$OUT/bench_$dev.json"
    { echo "## bench on $dev (exit $rc; 124 = timed out, the report then holds the runs done)"; echo; sed -e 's/^# torchakvf bench/### torchakvf bench/' \
        -e 's/^## /#### /' "/tmp/bench_$dev/report.md"; echo; } >> "$md"
  else
    { echo "## bench on $dev: no report (exit $rc; 124 = timed out); its log's last lines:"; echo; echo '```'
      grep -E "bench|error" "$OUT/bench_$dev.log" | tail -n 20; echo '```'; echo; } >> "$md"
  fi
done

# ---- 2b. full-resolution ta.akvf on CUDA against scipy eigsh on the CPU (issue 13's headline) ---
if [ "$has_cuda" = 1 ] && [ "$(left)" -gt 40 ]; then
  t=$(cap 75)
  echo "== full-resolution ta.akvf on cuda, PSB 21 and 301 (at most $t s)"
  timeout "$t" python3 benchmarks/akvf_fullres.py --psb "$psb" --device cuda --clock wall \
      --threads 0 --ids 21 301 --repeat 2 --decimate 0 --fresh 0 --out "$OUT/akvf_fullres_cuda.md" \
      > "$OUT/akvf_fullres_cuda.log" 2>&1
  rc=$?
  if [ -f "$OUT/akvf_fullres_cuda.md" ]; then
    { echo "## full-resolution ta.akvf on cuda (exit $rc)"; echo; sed -e 's/^# /### /' "$OUT/akvf_fullres_cuda.md"; echo; } >> "$md"
  else
    { echo "## full-resolution ta.akvf on cuda: no report (exit $rc; 124 = timed out)"; echo; echo '```'
      tail -n 15 "$OUT/akvf_fullres_cuda.log"; echo '```'; echo; } >> "$md"
  fi
fi

# ---- 3. CUDA against CPU ----------------------------------------------------------------------
python3 - "$OUT" <<'PY' >> "$md"
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
rep = {d: json.loads((out / f"bench_{d}.json").read_text()) for d in ("cuda", "cpu")
       if (out / f"bench_{d}.json").is_file()}
print("## Summary\n")
for d, r in rep.items():
    b = r["runs"]["batched"]
    rows = (r.get("budget_sweep") or {}).get("rows", [])
    sweep = ", ".join(f"{x['budget']}: {x['ratio']:.2f}x" for x in rows if x.get("ratio"))
    print(f"- {d}: batched {b['meshes_ok']}/{b['meshes']} meshes in {b['wall_seconds']:.1f} s "
          f"({b['workers']} worker(s)); one at a time / batched by face budget: {sweep or '-'}")
if len(rep) == 2:
    w = {d: r["runs"]["batched"]["wall_seconds"] for d, r in rep.items()}
    print(f"- cpu seconds / cuda seconds, batched, same meshes: {w['cpu'] / w['cuda']:.2f}x")
PY
echo "- check took $SECONDS s" >> "$md"
cat "$md" | sed -n '/^## Summary/,$p'
exit "$rc_tests"
