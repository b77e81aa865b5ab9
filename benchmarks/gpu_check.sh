#!/usr/bin/env bash
# deeplens GPU check (issue #40): the CUDA tests, tracer and adjoint-render throughput, EDOF and
# doublet training steps at 256 and 512 px, and a tiny `train.py ... trainer=gpu` run.  Writes
# one results file, <out>/gpu_check.md (markdown tables + every number as JSON).
#
#   bash benchmarks/gpu_check.sh --out DIR            # on the GPU machine (or OUT=DIR)
#   bash benchmarks/gpu_check.sh --out DIR --dry-run  # CPU, tiny sizes: the code paths only
#
# Set-up: `bash dev.sh setup` (a .venv with `pip install -e .[dev,docs]`, ~2 min on a fresh
# machine) unless GPU_CHECK_PYTHON names an interpreter that already has deeplens installed.
# Each section then runs in its own process under a hard `timeout` (budgets below, ~6 min in
# all; GPU_CHECK_TOTAL_S caps the sum).  A section that fails or times out is recorded as such
# and the next one runs; the report step always writes the results file.
set -uo pipefail
cd "$(dirname "$0")/.."

out=${OUT:-}
dry=()
device=()
while [ $# -gt 0 ]; do
    case "$1" in
        --out) out=$2; shift 2 ;;
        --out=*) out=${1#--out=}; shift ;;
        --dry-run) dry=(--dry-run); shift ;;
        --device) device=(--device "$2"); shift 2 ;;
        -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
        *) echo "gpu_check.sh: unknown argument $1 (expected --out DIR, --dry-run, --device D)" >&2
           exit 2 ;;
    esac
done
if [ -z "$out" ]; then
    echo "gpu_check.sh: give the results folder: --out DIR (or set OUT)" >&2
    exit 2
fi
mkdir -p "$out/gpu_check_parts"
out=$(cd "$out" && pwd)
parts=$out/gpu_check_parts

if [ -n "${GPU_CHECK_PYTHON:-}" ]; then
    py=$GPU_CHECK_PYTHON
else
    t0=$(date +%s)
    if ! timeout 600 bash dev.sh setup > "$parts/setup.log" 2>&1; then
        echo "gpu_check.sh: set-up failed (bash dev.sh setup); last lines of $parts/setup.log:" >&2
        tail -n 20 "$parts/setup.log" >&2
        exit 1
    fi
    echo "[gpu_check] set-up: $(( $(date +%s) - t0 )) s"
    py=.venv/bin/python
fi

# seconds per section (gpu_check.py's GPU_BUDGETS); a dry run gets 90 s each (it needs far less)
if [ ${#dry[@]} -gt 0 ]; then
    budgets="env:90 cuda_tests:90 trace:90 adjoint_render:90 train_step:90 e2e:90"
else
    budgets="env:20 cuda_tests:60 trace:40 adjoint_render:55 train_step:110 e2e:70"
fi
total=${GPU_CHECK_TOTAL_S:-360}
start=$(date +%s)
for entry in $budgets; do
    name=${entry%%:*}
    budget=${entry##*:}
    left=$(( total - ($(date +%s) - start) ))
    if [ ${#dry[@]} -eq 0 ] && [ "$left" -lt "$budget" ]; then
        budget=$(( left > 10 ? left : 10 ))
    fi
    rm -f "$parts/$name.json" "$parts/$name.rc"
    timeout -k 10 "$budget" "$py" benchmarks/gpu_check.py --section "$name" --out "$out" \
        --budget "$budget" "${dry[@]}" "${device[@]}" > "$parts/$name.log" 2>&1
    rc=$?
    echo "$rc" > "$parts/$name.rc"
    echo "[gpu_check] $name: exit $rc after $(( $(date +%s) - start )) s; $(grep '^\[gpu_check\]' "$parts/$name.log" | tail -n 1)"
done
"$py" benchmarks/gpu_check.py --report --out "$out" "${dry[@]}"
