#!/usr/bin/env bash
# Installs everything a fresh Debian machine needs: system libraries, then this package with all extras.
# Idempotent: safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."

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

# torch 2.13.0 CPU first, so nothing else drags in a CUDA build.
python3 -m pip install -q "torch==2.13.0"
python3 -m pip install -q -e ".[train,realsense,franka,dev]"
