#!/usr/bin/env bash
# Set up a local virtual environment for vcr-odom on a fresh Debian/Ubuntu machine.
# Idempotent: a second call only re-checks the system library and re-installs when pyproject.toml changed.
#   PYTHON      interpreter to build the venv from (default python3, needs >= 3.11)
#   VENV        venv folder (default .venv)
#   TORCH_SPEC  torch requirement installed first (default torch==2.13.0, a CPU build on this team's
#               machines; e.g. TORCH_SPEC="torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu")
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=${VENV:-.venv}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}

die() { echo "setup: error: $*" >&2; exit 1; }

ensure_libusb() {
    # open3d's Python module links against libusb-1.0 and fails to import without it.
    if ldconfig -p 2>/dev/null | grep -q 'libusb-1\.0\.so\.0'; then return 0; fi
    local how="install the system package libusb-1.0-0 (Debian/Ubuntu: sudo apt-get install libusb-1.0-0) and run again"
    command -v apt-get >/dev/null 2>&1 || die "open3d needs libusb-1.0 (libusb-1.0.so.0) and apt-get is not available: $how"
    local sudo=""
    if [ "$(id -u)" -ne 0 ]; then
        sudo -n true 2>/dev/null || die "open3d needs libusb-1.0, and installing it needs root (sudo asked for a password): $how"
        sudo="sudo -n"
    fi
    echo "setup: installing libusb-1.0-0 (needed by open3d)"
    export DEBIAN_FRONTEND=noninteractive
    $sudo apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 \
        || { $sudo apt-get update -q >/dev/null 2>&1 && $sudo apt-get install -y -q libusb-1.0-0 >/dev/null; } \
        || die "apt-get could not install libusb-1.0-0: $how"
}

ensure_python() {
    command -v "$PYTHON" >/dev/null 2>&1 || die "'$PYTHON' not found; set PYTHON to a Python >= 3.11"
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
        || die "$("$PYTHON" --version 2>&1) is too old; vcr-odom needs Python >= 3.11 (set PYTHON=...)"
    "$PYTHON" -c 'import venv, ensurepip' 2>/dev/null \
        || die "'$PYTHON' has no venv/ensurepip module (Debian/Ubuntu: sudo apt-get install python3-venv)"
}

install_packages() {
    local stamp="$VENV/.setup-stamp"
    if [ -f "$stamp" ] && [ "$stamp" -nt pyproject.toml ] && "$VENV/bin/python" -c 'import vcr_odom' 2>/dev/null; then
        return 0
    fi
    [ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install -q --upgrade pip
    # torch first, pinned: an unpinned torch would pull a multi-gigabyte CUDA build.
    "$VENV/bin/python" -c 'import torch' 2>/dev/null || "$VENV/bin/python" -m pip install -q $TORCH_SPEC
    "$VENV/bin/python" -m pip install -q -e ".[dev]"
    touch "$stamp"
}

ensure_python
ensure_libusb
install_packages
"$VENV/bin/python" -c 'import open3d, kiss_icp, evo, torch, vcr_odom' \
    || die "the environment in $VENV does not import; remove $VENV and run again"
echo "setup: ready ($VENV)"
