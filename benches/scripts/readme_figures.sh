#!/usr/bin/env bash
# Every performance figure README.md and benches/README.md quote, in one run on this machine:
# the machine, `splat4d bench` on the bench scenes (512×512 with the dense baseline, 1080p,
# 1M kernels), and whole `splat4d render` processes against the ceiling probe.
# Usage: bash benches/scripts/readme_figures.sh [OUT]   (from the repository root; ~6 min)
# Writes OUT/figures.txt (default out/figures); nothing else may run meanwhile.
set -euo pipefail
out=${1:-out/figures}
mkdir -p "$out"
cargo build --release --quiet
bin=target/release/splat4d
{
  echo "# machine"
  lscpu | grep -E "Model name|^CPU\(s\)"
  grep -o -w -E "avx2|fma|avx512f|avx512bw|avx512dq|avx512vl" /proc/cpuinfo | sort -u | tr '\n' ' '
  echo
  echo "# splat4d bench --frames 5"
  "$bin" bench --frames 5 2>/dev/null
  echo "# splat4d bench --scene 10k --scene 100k --size 1920x1080 --no-dense --frames 3"
  "$bin" bench --scene 10k --scene 100k --size 1920x1080 --no-dense --frames 3 2>/dev/null
  echo "# splat4d bench --scene 1m --no-dense --frames 3"
  "$bin" bench --scene 1m --no-dense --frames 3 2>/dev/null
  echo "# bash benches/scripts/whole_process.sh 9"
  bash benches/scripts/whole_process.sh 9 2>/dev/null
} | tee "$out/figures.txt"
