#!/usr/bin/env bash
# Installs what a fresh Debian machine needs: system libraries, then this package.
#   install.sh demo   the deploy side only (runtime, driver, hil_sim): what `make demo` needs, no torch
#   install.sh all    every extra (training, export, RealSense, Franka, dev tools): what `make test` needs
# Idempotent: safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."
extras=${1:-all}
case "$extras" in demo|all) ;; *) echo "usage: $0 demo|all" >&2; exit 2;; esac

# libosmesa6: headless MuJoCo rendering fallback (MUJOCO_GL=osmesa); libusb-1.0-0: pyrealsense2 imports need it.
need=()
for pkg in libusb-1.0-0 libosmesa6 libegl1; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -q || true
    $SUDO apt-get install -y -q "${need[@]}"
fi

if [ "$extras" = demo ]; then
    python3 -m pip install -q -e .
    exit 0
fi
# torch 2.13.0 CPU first, so nothing else drags in a CUDA build.
python3 -m pip install -q "torch==2.13.0"
python3 -m pip install -q -e ".[train,realsense,franka,dev]"
