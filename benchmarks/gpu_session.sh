#!/usr/bin/env bash
# The GPU measurements in as few device calls as possible (a lent machine's time is short and
# one command may run 10 minutes). Each phase fits in one call; results land in $OUT (or
# benchmarks/results/gpu when OUT is unset).
#
# warp-lang is not on the GPU image and its wheel (150 MB) is over what one call may carry
# (64 MiB), so it travels as an installed site folder, xz-packed and cut into parts of 56 MiB
# under .gpu/ (git-ignored), one part per call. Once, here (a machine with pip):
#     bash benchmarks/gpu_session.sh pack
# Then, on a warm lent machine, back to back (it goes back after 30 s idle):
#     run "bash benchmarks/gpu_session.sh receive" carrying .gpu/1     (parts land in /tmp/parts)
#     run "bash benchmarks/gpu_session.sh receive tests" carrying .gpu/2  (unpacks into /tmp/site; then
#                                            the CUDA and graph tests, CPU against CUDA)
#     run "bash benchmarks/gpu_session.sh switch"   # device_switch at 100k, 300k, 1M: --graph --mesh, then plain
#     run "bash benchmarks/gpu_session.sh access"   # lists against grid queries, slot- against particle-major
# ("all" adds 1 simulated second at 1M with --graph, kernel_profile at 100k and 1M, and
# breakdown at 1M with its files written; "receive check" runs the CUDA tests, every bundled
# scene through the CLI on CUDA with --graph (benchmarks/gallery.py) and DFSPH at 100k and 1M
# with --graph)
# or all of it in the second call, each phase under its own time limit (a session's device time
# is 15 minutes; the second call then carries .gpu/2 and .warp_cache, the CPU kernels built here):
#     run "bash benchmarks/gpu_session.sh receive all"
# Results land in $OUT as one archive, gpu_results.tgz, refreshed after each phase (at most 8
# files come back from a call, and a phase cut off by its limit keeps what the others wrote).
set -uo pipefail
cd "$(dirname "$0")/.."
phase="${1:?phase: pack, receive, all, check, tests, switch or access}"
WARP_VERSION="${WARP_VERSION:-1.19.0}"
SITE="${SITE:-/tmp/site}"
PARTS="${PARTS:-/tmp/parts}"

if [ "$phase" = pack ]; then
    work=$(mktemp -d)
    plat=""
    for p in manylinux_2_34_x86_64 manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_17_x86_64 manylinux2014_x86_64; do
        plat="$plat --platform $p"
    done
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $plat -d "$work/whl" \
        "warp-lang==$WARP_VERSION" "trimesh>=4" "meshio>=5.3" || exit 1
    python3 -m pip install -q --no-deps --no-compile --target "$work/site" "$work"/whl/*.whl || exit 1
    rm -rf "$work/site/warp/examples" "$work/site/warp/tests" "$work/site/bin"
    rm -rf .gpu && mkdir -p .gpu
    tar cf - -C "$work/site" . | xz -T0 -6 | split -b 56M -d -a 1 - "$work/site.tar.xz."
    n=0
    for part in "$work"/site.tar.xz.*; do
        n=$((n + 1)); mkdir -p ".gpu/$n"; mv "$part" ".gpu/$n/"
    done
    for d in .gpu/*/; do echo "$n" >"$d/parts"; done
    rm -rf "$work"
    du -sh .gpu/*
    exit 0
fi

if [ "$phase" = receive ]; then
    mkdir -p "$PARTS"
    cp .gpu/*/site.tar.xz.* "$PARTS"/ || exit 1
    n=$(cat .gpu/*/parts | head -1)
    have=$(ls "$PARTS" | wc -l)
    if [ "$have" -lt "$n" ]; then
        echo "received $have of $n parts; carry the next one"
        exit 0
    fi
    mkdir -p "$SITE" && cat "$PARTS"/site.tar.xz.* | xz -d | tar xf - -C "$SITE" || exit 1
    echo "unpacked $n parts into $SITE"
    phase="${2:-none}"
    [ "$phase" = none ] && exit 0
fi

final="${OUT:-benchmarks/results/gpu}"
out="$final"
[ "$phase" = all ] || [ "$phase" = check ] && out=/tmp/gpu_results && rm -rf "$out"
mkdir -p "$out" "$final"
[ -d "$SITE/warp" ] && export PYTHONPATH="$SITE:$PWD:${PYTHONPATH:-}"
cache=/tmp/warp_cache
[ -d .warp_cache ] && cache="$PWD/.warp_cache"
export PYTHONUNBUFFERED=1 WARP_CACHE_PATH="${WARP_CACHE_PATH:-$cache}"
nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.memory --format=csv >"$out/gpu.txt" 2>&1
python3 -c "import warp as wp; wp.init(); print('warp', wp.__version__, wp.get_device('cuda:0').name)" || exit 1

# one phase of "all": its commands under a limit of $1 seconds, then the archive refreshed
timed_phase() {
    local limit=$1 name=$2
    shift 2
    local t0=$SECONDS
    echo "=== $name (limit ${limit} s)"
    timeout -k 5 "$limit" bash -c "$*" >"$out/$name.log" 2>&1
    echo "=== $name: exit $? after $((SECONDS - t0)) s"
    tail -n 25 "$out/$name.log"
    tar czf "$final/gpu_results.tgz" -C "$out" .
}

case "$phase" in
all)
    timed_phase 130 tests "python3 -m pytest -q -rs tests -k 'cuda' -p no:cacheprovider"
    timed_phase 200 switch_graph_mesh "python3 benchmarks/device_switch.py --devices cuda --counts 100000,300000,1000000 --graph --mesh --out $out"
    timed_phase 90 switch_graph_long "python3 benchmarks/device_switch.py --devices cuda --counts 1000000 --graph --duration 1.0 --out $out"
    timed_phase 130 switch_plain "python3 benchmarks/device_switch.py --devices cuda --counts 100000,300000,1000000 --out $out"
    timed_phase 90 access "python3 benchmarks/neighbor_access.py --devices cuda --counts 100000,1000000 --repeats 10 --out $out"
    timed_phase 90 profile "python3 benchmarks/kernel_profile.py --counts 100000,1000000 --out $out"
    timed_phase 120 breakdown "python3 benchmarks/breakdown.py --device cuda --particles 1000000 --duration 0.25 --out $out"
    ;;
check)  # the CUDA tests, every bundled scene through the CLI on CUDA with --graph, DFSPH with graphs
    timed_phase 150 tests "python3 -m pytest -q -rs tests -k 'cuda' -p no:cacheprovider"
    timed_phase 240 gallery "python3 benchmarks/gallery.py --device cuda --graph --out $out/gallery"
    timed_phase 90 switch_dfsph "python3 benchmarks/device_switch.py --devices cuda --counts 100000,1000000 --graph --method dfsph --out $out"
    ;;
tests)
    python3 -m pytest -q -rs tests -k "cuda or graph" 2>&1 | tee "$out/tests.log"
    ;;
switch)
    python3 benchmarks/device_switch.py --devices cuda --counts 100000,300000,1000000 --graph --mesh --out "$out" 2>&1 | tee "$out/switch_graph_mesh.log"
    python3 benchmarks/device_switch.py --devices cuda --counts 100000,300000,1000000 --out "$out" 2>&1 | tee "$out/switch_plain.log"
    ;;
access)
    python3 benchmarks/neighbor_access.py --devices cuda --counts 100000,300000,1000000 --out "$out" 2>&1 | tee "$out/access.log"
    ;;
*)
    echo "unknown phase $phase: pack, receive, all, check, tests, switch or access" >&2
    exit 2
    ;;
esac
