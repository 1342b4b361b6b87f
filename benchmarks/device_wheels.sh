#!/usr/bin/env bash
# Fill .whl/ (gitignored) with the Python 3.12 wheels that a bare GPU machine lacks, for
# benchmarks/device_check.py (docs/gpu.md). The machine's image has jax with its CUDA plugin, flax,
# optax, numpy, scipy, scikit-learn, matplotlib, pillow, rich, typer, pandas, numba, msgpack, colorama
# and cloudpickle, and no package index: what worldagent needs beyond them travels as wheels,
# each pinned to the version installed here (the one the tests ran with), none to its dependencies
# (--no-deps: every one missing there is named below). Extra names (e.g. flax optax) are brought too.
#
#   . .venv/bin/activate && bash benchmarks/device_wheels.sh [NAME ...]
#
# Then, on the machine, from the repository root (carrying .whl):
#   python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
#   PYTHONPATH=/tmp/site:src PYTHONUNBUFFERED=1 python3 benchmarks/device_check.py --out "$OUT"
set -euo pipefail
cd "$(dirname "$0")/.."
MISSING=(gymnasium farama-notifications pettingzoo cma bayesian-optimization ribs array-api-compat numpy-groupies "$@")
LIMIT_MIB=60 # a device call carries at most 64 MiB, the working tree included

pinned() { # NAME==VERSION as installed here, else NAME (the newest)
    python - "$1" <<'EOF'
import sys
from importlib import metadata

try:
    print(f"{sys.argv[1]}=={metadata.version(sys.argv[1])}")
except metadata.PackageNotFoundError:
    print(sys.argv[1])
EOF
}

rm -rf .whl && mkdir -p .whl
for name in "${MISSING[@]}"; do
    python -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        -d .whl "$(pinned "$name")"
done
# The machine gets the working tree without .git: the commit measured travels beside the wheels.
python - <<'EOF'
import json, subprocess

head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip() or None
dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True).stdout.strip())
open(".whl/COMMIT", "w").write(json.dumps({"commit": head, "dirty": dirty}) + "\n")
EOF
git check-ignore -q .whl/COMMIT || { echo ".whl/ is not ignored by git: add /.whl/ to .gitignore" >&2; exit 1; }
size=$(du -sm .whl | cut -f1)
ls -1 .whl
echo ".whl: ${size} MiB (limit ${LIMIT_MIB})"
[ "$size" -le "$LIMIT_MIB" ] || { echo ".whl is over ${LIMIT_MIB} MiB: a device call would refuse it" >&2; exit 1; }
