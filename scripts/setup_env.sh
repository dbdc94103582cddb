#!/usr/bin/env bash
# Create (or refresh) the project virtual environment .venv with every Python dependency,
# the ROS 2 Jazzy client libraries from PyPI and the four aeropend packages.
# Idempotent: a second run only installs what changed. Needs Python >= 3.11.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${AEROPEND_VENV:-$ROOT/.venv}"
PY="${PYTHON:-python3}"

if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  echo "aeropend needs Python >= 3.11 (found: $("$PY" --version 2>&1))" >&2
  exit 1
fi
if [ ! -x "$VENV/bin/python" ]; then
  if ! "$PY" -m venv "$VENV" 2>/dev/null; then
    # Debian/Ubuntu ship venv separately
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
      apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
      "$PY" -m venv "$VENV"
    else
      echo "cannot create a venv: install python3-venv (sudo apt-get install python3-venv)" >&2
      exit 1
    fi
  fi
fi
# AVR toolchain + simavr for the firmware build and the emulated-MCU tests (issue 7):
# installed only when missing, only as root with apt-get (else those tests skip with a reason).
if ! command -v avr-gcc >/dev/null || ! command -v avr-size >/dev/null \
    || [ ! -f /usr/lib/avr/include/avr/io.h ] || [ ! -f /usr/include/simavr/sim_avr.h ]; then
  if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
    apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq gcc-avr avr-libc simavr libsimavr-dev \
      libsimavrparts1 >/dev/null
  else
    echo "note: gcc-avr/avr-libc/simavr missing and not root: firmware tests will skip" >&2
  fi
fi
stamp="$VENV/.aeropend-installed"
want="$(cat "$ROOT/requirements.txt" "$ROOT"/src/*/setup.py | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -r "$ROOT/requirements.txt"
  for pkg in aeropend_sim aeropend_control aeropend_bridge aeropend_ident; do
    "$VENV/bin/python" -m pip install -q --no-deps --no-build-isolation -e "$ROOT/src/$pkg"
  done
  echo "$want" > "$stamp"
fi
echo "aeropend environment ready: $VENV"
