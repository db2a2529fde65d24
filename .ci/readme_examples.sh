#!/usr/bin/env bash
# Runs every example command of README.md, in order, as a new user would after cloning:
# each ```sh block's `cargo run …` lines (continuation lines joined; `cargo test` is run by
# .ci/run itself). Usage examples with placeholders are ```text blocks and are not run.
# Exits at the first command that fails, naming it. From the repository root.
set -euo pipefail
cd "$(dirname "$0")/.."
mapfile -t commands < <(python3 - <<'PY'
import re
text = open("README.md", encoding="utf-8").read()
for block in re.findall(r"```sh\n(.*?)```", text, re.S):
    joined = re.sub(r"\\\n\s*", " ", block)
    for line in joined.splitlines():
        line = line.split("  #")[0].strip()
        if line.startswith("cargo run"):
            print(line)
PY
)
echo "README examples: ${#commands[@]} commands"
for command in "${commands[@]}"; do
  echo "== $command"
  start=$(date +%s)
  if ! bash -c "$command" > /tmp/readme_example.log 2>&1; then
    echo "README example failed: $command"
    tail -20 /tmp/readme_example.log
    exit 1
  fi
  echo "   ok in $(( $(date +%s) - start )) s: $(tail -1 /tmp/readme_example.log)"
done
