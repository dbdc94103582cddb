#!/usr/bin/env bash
# README command 1: set up everything, then run the main job on the simulated plant:
# sim_node + excitation + recorder as separate ROS 2 processes, then the grey-box baseline on the
# recorded bag. Writes reports/main/ (bag, report.json, overlay.png, summary.json).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup_env.sh
VENV="${AEROPEND_VENV:-$ROOT/.venv}"
exec "$VENV/bin/pipeline" --out "${AEROPEND_REPORT:-reports/main}" "$@"
