#!/usr/bin/env bash
# README command 1: set up everything, then run the main job on the simulated plant:
# sim_node + excitation + recorder as separate ROS 2 processes, then the grey-box baseline on the
# recorded bag. Writes reports/main/ (bag, report.json, overlay.png, summary.json).
# The folder is this script's own: a second run replaces the previous run there (pipeline
# --overwrite, which empties only a folder holding a main-job run, never another one).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup_env.sh
VENV="${AEROPEND_VENV:-$ROOT/.venv}"
OUT="${AEROPEND_REPORT:-reports/main}"
if [ -n "$(ls -A "$OUT" 2>/dev/null)" ]; then
  echo "run_main.sh: replacing the previous run in $OUT (pipeline --overwrite)"
fi
exec "$VENV/bin/pipeline" --out "$OUT" --overwrite "$@"
