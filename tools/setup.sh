#!/usr/bin/env bash
# Set up graphcal on a fresh Debian machine with Python 3.11: the system library open3d needs
# (libusb-1.0-0, installed with apt-get as root, or through sudo), a virtual environment in
# .venv and the package with its test extras. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = 0 ]; then SUDO=""; elif command -v sudo >/dev/null; then SUDO="sudo"; else
    echo "graphcal setup: open3d needs libusb-1.0-0; as root run: apt-get install -y libusb-1.0-0" >&2; exit 1
  fi
  $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 \
    || { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null; }
fi

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null || PYTHON=python3
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
log=$(mktemp)
if ! { .venv/bin/python -m pip install -q --upgrade pip && .venv/bin/python -m pip install -q -e ".[test]"; } >"$log" 2>&1; then
  cat "$log" >&2; echo "graphcal setup: pip install failed" >&2; exit 1
fi
rm -f "$log"
.venv/bin/python -c "import open3d, gtsam, graphcal" || { echo "graphcal setup: import check failed" >&2; exit 1; }
