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
# AVR toolchain + simavr for the firmware build and the emulated-MCU tests (issue 7). Debian /
# Ubuntu packages: gcc-avr (avr-gcc; pulls binutils-avr: avr-size/avr-nm/avr-objcopy), avr-libc,
# simavr, libsimavr-dev (headers + libsimavr/libsimavrparts; pulls libsimavr2, libsimavrparts1,
# libelf1) and, for the harness and the host-compiled C unit tests, gcc, make, libc6-dev.
# Only the packages not yet installed are installed, as root or through passwordless sudo;
# otherwise the firmware tests skip with a reason. AEROPEND_SKIP_APT=1 skips this block.
AVR_PKGS="gcc-avr binutils-avr avr-libc simavr libsimavr-dev libsimavrparts1 gcc make libc6-dev"
if [ "${AEROPEND_SKIP_APT:-0}" != 1 ] && command -v dpkg-query >/dev/null; then
  missing=""
  for pkg in $AVR_PKGS; do
    status="$(dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null || true)"
    [ "$status" = "install ok installed" ] || missing="$missing $pkg"
  done
  if [ -n "$missing" ]; then
    if [ "$(id -u)" = 0 ]; then SUDO=""
    elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then SUDO="sudo -n"
    else SUDO="none"
    fi
    if [ "$SUDO" != none ] && command -v apt-get >/dev/null; then
      echo "installing:$missing" >&2
      $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq >/dev/null \
        && $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
          $missing >/dev/null \
        || echo "note: apt-get could not install$missing: firmware tests will skip" >&2
    else
      echo "note: missing$missing and neither root nor passwordless sudo: firmware tests will skip" \
        "(sudo apt-get install$missing)" >&2
    fi
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
