#!/usr/bin/env bash
# The Python package (python/), as a new user installs it: a fresh virtual environment,
# numpy, pytest and torch from the registry, the wheel built from this clone by the README's
# command, then the Python examples of README.md and docs/, python/examples/ on a short
# run, and python/tests with pytest. From the repository root; run by .ci/run after the cargo steps.
# SPLAT4D_VENV reuses a folder for the environment (default: a new temporary one).
set -euo pipefail
cd "$(dirname "$0")/.."
command -v python3 >/dev/null || { echo "python3 (3.9 or newer) is required"; exit 1; }
if [ -n "${SPLAT4D_VENV:-}" ]; then
  venv=$SPLAT4D_VENV
else
  scratch=$(mktemp -d)
  venv=$scratch/venv
  # torch alone is about 5 GB installed: not left behind.
  trap 'rm -rf "$scratch"' EXIT
fi
step() { echo "== python: $1 ($(( $(date +%s) - start )) s so far)"; }
start=$(date +%s)
python3 -m venv "$venv"
export PATH="$venv/bin:$PATH"
step "installing maturin, numpy, pytest, torch and gsplat (torch's wheel is large: about 2 minutes)"
pip install --quiet --disable-pip-version-check maturin numpy pytest torch
# gsplat's own torch reference, for the comparison of python/examples/compare_gsplat.py (a
# pure-Python wheel: its CUDA code is compiled only when used, and this never uses it).
pip install --quiet --disable-pip-version-check gsplat
step "building and installing the wheel (pip install ./python)"
# maturin from the environment (installed above), not a second download in an isolated one;
# the release profile without its link-time optimisation across crates (docs/architecture.md,
# "Quicker rebuilds"): the same bits, built in a fraction of the time.
CARGO_PROFILE_RELEASE_LTO=false CARGO_PROFILE_RELEASE_CODEGEN_UNITS=16 \
  pip install --quiet --disable-pip-version-check --no-build-isolation ./python
python -c "import splat4d; print('splat4d', splat4d.__version__, 'from', splat4d.__file__)"
step "the Python examples of README.md and docs/ (\`\`\`python blocks, not \`\`\`python no-ci)"
python - <<'PY'
import glob, re
ran = 0
for name in ["README.md"] + sorted(glob.glob("docs/*.md")):
    text = open(name, encoding="utf-8").read()
    for block in re.findall(r"^```python[ \t]*\n(.*?)^```", text, re.S | re.M):
        print(f"-- {name}: {block.splitlines()[0]}")
        exec(compile(block, name, "exec"), {})
        ran += 1
assert ran, "README.md and docs/ have no ```python example"
PY
step "python/examples (short runs)"
for example in python/examples/*.py; do
  python "$example" --quick
done
step "pytest python/tests (the last lines below are pytest's)"
status=0
(cd python/tests && python -m pytest -q -p no:cacheprovider) || status=$?
if [ "$status" -eq 5 ]; then
  # pytest's 5: it collected no test, which here means the suite went missing.
  echo "pytest collected no test in python/tests"
  exit 1
fi
exit "$status"
