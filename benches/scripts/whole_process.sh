#!/usr/bin/env bash
# Whole `splat4d render` processes (load a 4D PLY, render, write an EXR) against the ceiling
# probe measured in the same run: useful pairs per second over the probe's, per thread count.
# Usage: bash benches/scripts/whole_process.sh [runs]   (from the repository root; ~1 min)
set -euo pipefail
runs=${1:-7}
cargo build --release --quiet
cargo build --release --quiet -p splat4d-benches --example bench_scene_file
bin=target/release/splat4d
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
target/release/examples/bench_scene_file 100000 1920 1080 "$dir/s100k.ply" "$dir/c1080.json"
target/release/examples/bench_scene_file 10000 512 512 "$dir/s10k.ply" "$dir/c512.json"
target/release/examples/bench_scene_file 100000 1920 1080 "$dir/a100k.ply" "$dir/c1080.json" 0.5
target/release/examples/bench_scene_file 0 512 512 "$dir/empty.ply" "$dir/c512.json"
ceilings=$("$bin" bench --ceiling 2>/dev/null)
echo "$ceilings"
# Median wall time of $runs runs of a command, in seconds: each process timed alone from
# Python (`date` around it would add two processes' start-up to every run).
median_time() {
  python3 - "$runs" "$@" <<'PY'
import statistics, subprocess, sys, time
runs, command = int(sys.argv[1]), sys.argv[2:]
times = []
for _ in range(runs):
    start = time.perf_counter()
    subprocess.run(command, stdout=subprocess.DEVNULL, check=True)
    times.append(time.perf_counter() - start)
print(statistics.median(times))
PY
}
for threads in 1 2; do
  ceiling=$(echo "$ceilings" | grep "^ceiling probe ($(echo "$ceilings" | head -1 | sed 's/.*(\([a-z0-9]*\) path.*/\1/') path, $threads thread" | sed 's/.*: \([0-9.e+]*\) pairs.*/\1/')
  for case in "s100k.ply c1080.json" "s10k.ply c512.json"; do
    set -- $case
    pairs=$("$bin" render --scene "$dir/$1" --camera "$dir/$2" --time 0.5 --out "$dir/o.exr" --threads "$threads" | sed 's/.* \([0-9]*\) pairs$/\1/')
    median=$(median_time "$bin" render --scene "$dir/$1" --camera "$dir/$2" --time 0.5 --out "$dir/o.exr" --threads "$threads")
    python3 -c "
p, t, c = $pairs, $median, $ceiling
print(f'{\"$1\":>10} {\"$threads\"} thread(s): median {t*1e3:.1f} ms, {p/1e6:.1f} M pairs, {p/t:.3e} pairs/s = {100*p/t/c:.1f}% of the ceiling')"
  done
done
# An empty scene at 512×512, as a PNG, against `splat4d --version`.
for command in "render --scene $dir/empty.ply --camera $dir/c512.json --time 0.5 --out $dir/e.png" "--version"; do
  median=$(median_time "$bin" $command)
  echo "splat4d ${command%% *} (${command##*/}): median $(python3 -c "print(f'{$median*1e3:.2f}')") ms"
done
# The alpha blend on the same 100k kernels at opacity 0.5, against the additive, 2 threads.
for scene in s100k.ply a100k.ply; do
  median=$(median_time "$bin" render --scene "$dir/$scene" --camera "$dir/c1080.json" --time 0.5 --out "$dir/o.exr" --threads 2)
  echo "$scene 2 threads: median $(python3 -c "print(f'{$median*1e3:.0f}')") ms"
done
