#!/bin/bash
# The GPU engine's figures on a real GPU in one run (issue 40's targets; docs/results.md,
# "GPU engine"): bench of the seeded scenario-1 network in f32 and f64 with both tiled GEMM
# kernels, CROWN, where a step's time goes (--profile), the paper's 12 boxes with the pipelines
# cold and cached against the CPU engine, the GEMM kernels at small batches, verify 256 × 256
# on the GPU, scenario 2's 40 × 16 cells with and without --taylor3, and the GPU tests with their ignored whole-grid cases on that adapter. Roughly
# 11 minutes on an H200, most of it the GPU tests and the cold compiles.
#
#   benches/gpu-checks.sh [OUT]        # OUT: where the logs go (default: gpu-checks/)
#
# Runs from the repository root with `cargo` (or CBFREACH=path/to/cbfreach and the test
# binaries as GPU_TESTS="path/to/gpu_parity path/to/gpu_pipelines …", built elsewhere). Every
# stage has its own time limit, so one slow stage leaves the others' figures.
set -u
out=${1:-gpu-checks}
mkdir -p "$out"
log=$out/log.txt
start=$(date +%s)
stage() { echo "=== [$(($(date +%s) - start)) s] $*" | tee -a "$log"; }
# run LIMIT CMD…: the command's output to the log, then its status and wall time.
run() {
    local limit=$1
    shift
    local t0
    t0=$(date +%s%N)
    timeout "$limit" "$@" >>"$log" 2>&1
    local rc=$?
    echo "--- status $rc, $((($(date +%s%N) - t0) / 1000000)) ms: $*" | tee -a "$log"
}

if [ -z "${CBFREACH:-}" ]; then
    cargo build --release --bins --tests >>"$log" 2>&1 || { echo "build failed: $log"; exit 1; }
    CBFREACH=target/release/cbfreach
    GPU_TESTS=""
    for name in gpu_parity gpu_pipelines gpu_matches_cpu; do
        # The newest build of each test binary (cargo names them name-hash).
        newest=$(ls -t target/release/deps/"$name"-* | grep -v '\.d$' | head -1)
        GPU_TESTS="$GPU_TESTS $newest"
    done
fi
export CBFREACH_CACHE_DIR=${CBFREACH_CACHE_DIR:-$out/pipeline-cache} CBFREACH_REQUIRE_GPU=1
{ nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv 2>/dev/null; nproc; } >>"$log"

stage "adapter"
run 60 "$CBFREACH" bench --backend gpu --boxes 256 --steps 2 --bounds forward
grep -q "gpu (" "$log" || { stage "no GPU adapter: stop"; exit 3; }

for precision in f32 f64; do
    for gemm in tiles wide; do
        stage "bench $precision, GEMM $gemm"
        run 120 "$CBFREACH" bench --backend gpu --boxes 256,4096,16384,65536 --steps 50 \
            --bounds forward,forward-backward --"$precision" --gemm "$gemm"
    done
done
stage "CROWN, profiles"
run 90 "$CBFREACH" bench --backend gpu --boxes 4096,16384 --steps 10 --bounds crown --f32
for gemm in tiles wide; do
    for precision in f32 f64; do
        run 60 "$CBFREACH" bench --backend gpu --boxes 16384 --steps 5 --bounds forward-backward \
            --"$precision" --gemm "$gemm" --profile
    done
done
stage "small batches: the three GEMM kernels at the paper's 12 boxes and 64"
# A 400 × 36 output is 7 of the tiled kernel's 64 × 64 tiles (a few of the GPU's SMs busy),
# 225 of the flat kernel's workgroups: which is faster there decides `Gemm`'s default for
# small runs (all three give the same bits).
for gemm in flat tiles wide; do
    run 60 "$CBFREACH" bench --backend gpu --boxes 12,64 --steps 50 --bounds forward-backward \
        --f64 --gemm "$gemm"
    run 60 "$CBFREACH" bench --backend gpu --boxes 12 --steps 5 --bounds forward-backward \
        --f64 --gemm "$gemm" --profile
done
stage "the CPU engine beside the GPU"
run 120 "$CBFREACH" bench --backend cpu,gpu --boxes 12,256,16384 --steps 20 --bounds forward-backward

stage "the paper's 12 boxes: CPU, GPU cold, GPU cached"
# The JSONs (p12-*.json) compare the engines' sets box by box and step by step.
for time in continuous euler; do
    run 60 "$CBFREACH" reach scenarios/integrator.toml --time "$time" --backend cpu \
        --json "$out/p12-$time-cpu.json"
    rm -rf "$CBFREACH_CACHE_DIR"
    run 180 "$CBFREACH" reach scenarios/integrator.toml --time "$time" --backend gpu
    run 60 "$CBFREACH" reach scenarios/integrator.toml --time "$time" --backend gpu \
        --json "$out/p12-$time-gpu.json"
done

stage "verify 256 × 256 on the GPU: Euler, then the scenario's default (continuous)"
run 120 "$CBFREACH" verify scenarios/integrator.toml --grid 256,256 --backend gpu --time euler
run 300 "$CBFREACH" verify scenarios/integrator.toml --grid 256,256 --backend gpu

stage "what --taylor3 costs on the GPU (off by default until measured here; design §7.4)"
for t3 in "" --taylor3; do
    run 150 "$CBFREACH" verify scenarios/double-integrator.toml --grid 40,16 --face-local \
        --backend gpu $t3 --json "$out/di-40x16${t3:+-taylor3}.json"
done

stage "GPU tests on this adapter, ignored cases included"
for t in ${GPU_TESTS:-}; do
    run 600 "$t" --include-ignored
done
stage "done: $log"
