#!/usr/bin/env bash
# Re-records tests/data/recorded/outputs from commands.txt with the release binary.
# Only for a deliberate change of output: say which change in the commit message.
set -euo pipefail
cd "$(dirname "$0")/../../.."
cargo build --release --quiet
bin=target/release/splat4d
out=tests/data/recorded/outputs
rm -rf "$out" && mkdir -p "$out"
grep -v '^#' tests/data/recorded/commands.txt | grep -v '^$' | while read -r line; do
  line=${line//\$IN/tests\/data}
  line=${line//\$DATA/data}
  line=${line//\$OUT/$out}
  # shellcheck disable=SC2086
  "$bin" $line >/dev/null
done
# The output markers (.splat4d-output) name the run's files and are set aside by the test.
find "$out" -name .splat4d-output -delete
find "$out" -type f | sort | xargs sha256sum > tests/data/recorded/sha256.txt
du -sh "$out"
