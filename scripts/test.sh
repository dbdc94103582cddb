#!/usr/bin/env bash
# README command 2: set up everything and run the whole test suite (lint + pytest).
# pytest runs in parallel worker processes (pytest-xdist): AEROPEND_TEST_WORKERS of them (default
# below, chosen by measurement on a 2-core machine: docs/testing.md). Arguments go to pytest; one
# that sets the workers itself (-n N, -n0, --numprocesses, -p no:xdist) replaces the default.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup_env.sh
VENV="${AEROPEND_VENV:-$ROOT/.venv}"
"$VENV/bin/ruff" check src test bench tools
parallel=(-n "${AEROPEND_TEST_WORKERS:-3}" --dist loadgroup)
for arg in "$@"; do
  case "$arg" in
    -n|-n*|--numprocesses|--numprocesses=*|no:xdist|--dist|--dist=*) parallel=() ;;
  esac
done
set +e
"$VENV/bin/python" -m pytest "${parallel[@]}" "$@"
rc=$?
set -e
if [ "$rc" = 5 ]; then
  echo "pytest collected no tests: that is a failure" >&2
  exit 1
fi
exit "$rc"
