#!/usr/bin/env bash
# Runs every example command of README.md and of the manual (docs/*.md), in order (README
# first, then docs/ by file name), as a new user would after cloning.
#
# Marking convention, in the Markdown files:
# - a fenced block opened with ```sh is run: each of its `cargo run …` lines (continuation
#   lines joined, a trailing `  # comment` dropped); `cargo test` is run by .ci/run itself;
# - a block opened with ```sh no-ci is shown as shell (GitHub colours it) but NOT run: for
#   commands that serve until stopped (`splat4d view`) or take too long for CI; say why next
#   to it in the text;
# - usage synopses with placeholders are ```text blocks and are not run.
# A command already run earlier (the same text) is not run again.
# Exits at the first command that fails, naming it and its file. From the repository root.
set -euo pipefail
cd "$(dirname "$0")/.."
mapfile -t commands < <(python3 - <<'PY'
import glob, re
files = ["README.md"] + sorted(glob.glob("docs/*.md"))
seen = set()
for name in files:
    text = open(name, encoding="utf-8").read()
    for block in re.findall(r"^```sh[ \t]*\n(.*?)^```", text, re.S | re.M):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = line.split("  #")[0].strip()
            if line.startswith("cargo run") and line not in seen:
                seen.add(line)
                print(f"{name}\t{line}")
PY
)
echo "README and docs/ examples: ${#commands[@]} commands"
for entry in "${commands[@]}"; do
  file=${entry%%$'\t'*}
  command=${entry#*$'\t'}
  echo "== $file: $command"
  start=$(date +%s)
  if ! bash -c "$command" > /tmp/readme_example.log 2>&1; then
    echo "example of $file failed: $command"
    tail -20 /tmp/readme_example.log
    exit 1
  fi
  echo "   ok in $(( $(date +%s) - start )) s: $(tail -1 /tmp/readme_example.log)"
done
