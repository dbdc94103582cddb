#!/usr/bin/env bash
# README command 2: set up everything and run the whole test suite (lint + pytest).
# pytest runs in parallel worker processes (pytest-xdist): AEROPEND_TEST_WORKERS of them (default
# below, chosen by measurement on a 2-core machine: docs/testing.md). Arguments go to pytest; one
# that sets the workers itself (-n N, -n0, --numprocesses, -p no:xdist) replaces the default.
# Tests marked exclusive (real-time hardware in the loop) then run alone, in one process; an
# argument that selects by marker (-m ...) makes it one run, as asked.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup_env.sh
VENV="${AEROPEND_VENV:-$ROOT/.venv}"
# Python may write its bytecode caches: with PYTHONDONTWRITEBYTECODE set (some shells and CI images set
# it) every pytest worker and every process a test starts compiled the sources anew, and pytest
# rewrote every test module's asserts at each collection (collection 12.7 s instead of 4.4 s;
# docs/testing.md). The caches go to __pycache__/ folders, which git ignores.
unset PYTHONDONTWRITEBYTECODE
"$VENV/bin/ruff" check src test bench tools
parallel=(-n "${AEROPEND_TEST_WORKERS:-3}" --dist loadgroup)
split=1  # the tests marked exclusive (real-time hardware in the loop) run after the others, alone
alone=(-n 0)
for arg in "$@"; do
  case "$arg" in
    no:xdist) parallel=(); alone=() ;;
    -n|-n*|--numprocesses|--numprocesses=*|--dist|--dist=*) parallel=() ;;
    -m|-m*) split=0 ;;  # the caller selects by marker: one run, as asked
  esac
done
set +e
if [ "$split" = 1 ]; then
  # the parallel run stores which test files hold an exclusive test; the run alone imports only those
  # (test/conftest.py, AEROPEND_EXCLUSIVE_FILES), instead of collecting the whole suite a second time
  token="$$-$(date +%s%N)"
  AEROPEND_EXCLUSIVE_FILES="list:$token" "$VENV/bin/python" -m pytest "${parallel[@]}" -m "not exclusive" "$@"
  rc=$?
  AEROPEND_EXCLUSIVE_FILES="only:$token" "$VENV/bin/python" -m pytest "${alone[@]}" -m exclusive "$@"
  rc_alone=$?
  # 5: nothing collected; a failure only when neither part collected a test
  if [ "$rc" = 5 ] && [ "$rc_alone" != 5 ]; then rc=0; fi
  if [ "$rc_alone" != 0 ] && [ "$rc_alone" != 5 ] && [ "$rc" = 0 ]; then rc=$rc_alone; fi
else
  "$VENV/bin/python" -m pytest "${parallel[@]}" "$@"
  rc=$?
fi
set -e
if [ "$rc" = 5 ]; then
  echo "pytest collected no tests: that is a failure" >&2
  exit 1
fi
exit "$rc"
