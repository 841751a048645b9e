#!/usr/bin/env bash
# Two prepared device calls for a session that is lent a GPU (issue 24): the CUDA tests, then the figures the
# open issues ask for on a GPU, each step bounded in time so that each part (one call, at most 10 minutes)
# returns all of its figures. Part 1 is device call 2 of ../shared/gpu/README.md (after Warp is staged),
# part 2 the next call on the same warm machine; from the repository root:
#
#   cp ../shared/gpu/bench_gpu.py .gpu/b/ && chmod 644 .gpu/b/bench_gpu.py  # here, before the call (not in the tree;
#     a read-only copy did not arrive on the device on 2026-11-26)
#   bash .gpu/b/stage_b.sh && source $HOME/gpu/env.sh && bash benchmarks/gpu_check.sh 1
#   bash benchmarks/gpu_check.sh 2                # call 3, on the same warm machine
#   bash benchmarks/gpu_check.sh 3                # or: the side-by-side figures alone (~350 s)
#
# Every step writes into $OUT (the device tool brings it back); a step that fails or runs out of time is
# recorded in $OUT/steps.txt and the script goes on, so one slow step never costs the others' figures.
# Budget (seconds, the steps' time limits): part 1 = tests 180, graphs 60, drape/xpbd harness 150 (about
# 400 s with start-up); part 2 = fits of tracks and footage 150, FEM 120, drape/XPBD rows 120, fit rows 150
# (540 s), with the fit rows' CPU side (one core, 300 s) running beside them on core 0 while the other steps
# are pinned to the remaining cores. Each part fits one 10-minute call; no argument runs both.
#
# The drape and XPBD rows at 256² and 512² compute their converged references on the GPU (seconds there,
# an hour of one CPU core at 512²) into $OUT/bench_cache: commit those .npz files (31 numbers each) to
# pliant/bench/references/ so that later runs, on any device, find them stored.
set -u
OUT=${OUT:-out/gpu}
mkdir -p "$OUT"
DEV=${DEV:-cuda:0}
PART=${1:-all}
PY=${PY:-python3}
export PYTHONPATH=${PYTHONPATH:-}:$PWD

step() {  # step NAME SECONDS COMMAND...: run one step under a time limit, log its exit code and wall time
    local name=$1 limit=$2
    shift 2
    local t0=$SECONDS
    timeout "$limit" "$@" >"$OUT/$name.log" 2>&1
    echo "$name rc=$? wall_s=$((SECONDS - t0))" | tee -a "$OUT/steps.txt"
}

nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv >"$OUT/gpu.txt" 2>&1
$PY -c "import warp as wp; wp.init(); print(wp.__version__, wp.get_cuda_devices())" >>"$OUT/gpu.txt" 2>&1

part() { [ "$PART" = all ] || [ "$PART" = "$1" ]; }

if part 1; then
# 1. Correctness on CUDA: every device-parametrised test, graph replay equal to direct steps, the examples.
step tests 180 $PY -m pytest -q -n 8 -p no:cacheprovider -k cuda \
    tests/test_devices.py tests/test_devices_grad.py tests/test_graph.py tests/test_diff_graph.py \
    tests/test_collisions.py tests/test_gaussians.py tests/test_gaussians_bind.py tests/test_implicit_pcg.py
# 2. Graph replay against launch by launch, side by side, every scene the Simulator can replay.
step graphs 60 $PY benchmarks/bench_graph.py --device "$DEV" --rounds 3 --frames 10
# 3. The measured gap: pliant against Newton on the drape and XPBD (harness of ../shared/gpu).
if [ -f .gpu/b/bench_gpu.py ]; then
    step harness 150 $PY .gpu/b/bench_gpu.py "$DEV" "$OUT/rows.jsonl" drape xpbd
fi
fi

if part 2; then
export PLIANT_BENCH_CACHE="$OUT/bench_cache"  # references computed on the GPU come back with $OUT
# 7b. Issue 24's fit figure, its CPU side: the same rows on one core (taskset), beside the GPU steps.
NCPU=$(nproc)
REST=""
if [ "$NCPU" -ge 4 ]; then
    REST="taskset -c 1-$((NCPU - 1))"  # the GPU steps keep off core 0
    step fit_rows_cpu 300 taskset -c 0 $PY -m pliant.cli bench fit_rope fit_cloth_17 --device cpu \
        --json "$OUT/fit_rows_cpu.jsonl" &
    CPU_FITS=$!
fi
# 4. Issues 25 and 30's figures on a GPU: the default fits of MuJoCo's cloth tracks and footage.
step fit_tracks 60 $REST $PY -m pliant.cli fit tests/data/foreign/mujoco_cloth.toml \
    tests/data/foreign/mujoco_cloth.npz --out "$OUT/fit_tracks" --device "$DEV" --no-video -q
step fit_footage 90 $REST $PY -m pliant.cli fit tests/data/foreign/mujoco_cloth.toml \
    tests/data/foreign/mujoco_cloth_video.npz --out "$OUT/fit_footage" --device "$DEV" --no-video -q
# 5. Issue 24 item 3: the device Newton (frames replayed as graphs) on the soft box, beside Newton with Warp's
#    CG (host decisions) at 10³; the CPU's L-BFGS row (91 ms per step at 30³ on one core) is the target.
step fem_pcg 120 $REST $PY -m pliant.cli bench soft_box_drop_10_implicit_pcg soft_box_drop_10_implicit_newton \
    soft_box_drop_30_implicit_pcg --device "$DEV" --json "$OUT/fem_pcg.jsonl"
# 6. Issue 24 item 6: the drape at 256² and 512² (bytes per substep, fraction of the peak bandwidth) and
#    XPBD at 256², each with its trajectory_error against a reference computed here (PLIANT_BENCH_CACHE).
#    --graph: frames replayed as captured CUDA graphs, as the Simulator runs them (XPBD's rows were launched
#    one by one until 2026-11-26: 154 fps at 64² against Newton's 578 in a graph).
step drape_rows 120 $REST $PY -m pliant.cli bench cloth_drape_256_symplectic cloth_drape_512_symplectic \
    xpbd_cloth_drape_64_coloring xpbd_cloth_drape_128_coloring xpbd_cloth_drape_256_coloring \
    xpbd_cloth_drape_256_jacobi xpbd_cloth_drape_64_jacobi_sum xpbd_cloth_drape_128_jacobi_sum \
    xpbd_cloth_drape_256_jacobi_sum --graph --device "$DEV" --json "$OUT/drape_rows.jsonl"
# 7a. Issue 24's fit figure: the README fit and the 17×17 cloth fit on the GPU (wall time, accuracy).
step fit_rows 150 $REST $PY -m pliant.cli bench fit_rope fit_cloth_17 --device "$DEV" \
    --json "$OUT/fit_rows.jsonl"
if [ -n "$REST" ]; then
    wait "$CPU_FITS"
else  # too few cores to keep one aside: the CPU side after the GPU steps (over budget: shorten it)
    step fit_rows_cpu 200 $PY -m pliant.cli bench fit_rope fit_cloth_17 --device cpu \
        --json "$OUT/fit_rows_cpu.jsonl"
fi
fi
if part 3; then
# 8. Issue 24's side-by-side figures in one call (what the README's GPU tables quote, 2026-11-26, ~350 s):
#    the drape and XPBD against Newton (harness of ../shared/gpu, both in CUDA graphs), pliant's rows replayed
#    as graphs (the 512² bandwidth fraction), Newton's VBD on the 30³ box beside the device Newton.
export PLIANT_BENCH_CACHE="$OUT/bench_cache"
step tests3 60 $PY -m pytest -q -n 8 -p no:cacheprovider -k cuda tests/test_drape_variants.py \
    tests/test_collisions.py tests/test_implicit_pcg.py
if [ -f .gpu/b/bench_gpu.py ]; then
    step harness_drape 90 $PY .gpu/b/bench_gpu.py "$DEV" "$OUT/harness_drape.jsonl" drape
    step harness_xpbd 100 $PY .gpu/b/bench_gpu.py "$DEV" "$OUT/harness_xpbd.jsonl" xpbd
fi
step rows3 60 $PY -m pliant.cli bench cloth_drape_512_symplectic cloth_drape_64_symplectic \
    xpbd_cloth_drape_64_jacobi_sum xpbd_cloth_drape_128_jacobi_sum xpbd_cloth_drape_256_jacobi_sum \
    --graph --device "$DEV" --json "$OUT/rows3.jsonl"
step vbd 150 $PY benchmarks/peers/box_vbd.py "$DEV" "$OUT/box_vbd.jsonl" --n 30 --settings 10x10,40x10 \
    --pliant-settings 5:float32,10:float32 --max-s 140
fi
cat "$OUT/steps.txt"
