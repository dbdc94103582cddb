#!/usr/bin/env bash
# README command 2: set up everything and run the whole test suite (lint + pytest).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup_env.sh
VENV="${AEROPEND_VENV:-$ROOT/.venv}"
"$VENV/bin/ruff" check src test bench tools
set +e
"$VENV/bin/python" -m pytest "$@"
rc=$?
set -e
if [ "$rc" = 5 ]; then
  echo "pytest collected no tests: that is a failure" >&2
  exit 1
fi
exit "$rc"
