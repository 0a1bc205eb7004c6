#!/usr/bin/env bash
# Set up everything quash-plugins needs on a fresh machine, into ./.venv.
# Idempotent: re-running only installs what changed. Used by `make demo` and `make test`.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON="${PYTHON:-python3}"
VENV="${VENV:-.venv}"

"$PYTHON" - <<'PY' || { echo "quash-plugins needs Python >= 3.11 (set PYTHON=python3.11)"; exit 1; }
import sys
sys.exit(0 if sys.version_info >= (3, 11) else 1)
PY

# OS packages: libusb for open3d, Chromium for the web-viewer test. Best effort: skipped
# without root or apt (the browser test then skips with a reason).
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  missing=()
  dpkg -s libusb-1.0-0 >/dev/null 2>&1 || missing+=(libusb-1.0-0)
  command -v chromium >/dev/null 2>&1 || missing+=(chromium)
  if [ ${#missing[@]} -gt 0 ]; then
    echo "[setup] apt-get install ${missing[*]}"
    # Keep-Downloaded-Packages=false: the .deb files are deleted once installed.
    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
      -o APT::Keep-Downloaded-Packages=false "${missing[@]}" >/dev/null
  fi
fi

# Free space where the venv goes, in MB: checked before each large step, because pip that
# runs out of disk half-way leaves a half-installed venv and an OSError that names no size.
need_space() {  # need_space MB WHAT
  local dir="$VENV" free
  [ -d "$dir" ] || dir="$(dirname "$VENV")"
  free=$(df -Pm "$dir" | awk 'NR==2 {print $4}')
  if [ -n "$free" ] && [ "$free" -lt "$1" ]; then
    echo "[setup] $2 needs about $1 MB free in $(cd "$dir" && pwd); $free MB are." >&2
    echo "[setup] Free some space there, or set VENV=/a/roomier/folder (QUASH_SKIP_DISK_CHECK=1 skips this check)." >&2
    [ "${QUASH_SKIP_DISK_CHECK:-0}" = 1 ] || exit 1
  fi
}

if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup] creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip install --quiet --disable-pip-version-check)
# Some machines' pip configs name index folders that do not exist; drop that noise only.
quiet_pip() { "${PIP[@]}" "$@" 2> >(grep -v "^WARNING: Location '" >&2); }

# torch first, pinned: open_clip needs torchvision, and this pair is known to import
# together (a bare `torch` would pull several GB of other builds).
if ! "$VENV/bin/python" -c "import torch, torchvision" >/dev/null 2>&1; then
  # torch 2.14.1 is a CUDA build: with its nvidia-* and triton wheels, about 5.6 GB.
  need_space 6500 "torch + torchvision (a CUDA build)"
  echo "[setup] installing torch + torchvision"
  quiet_pip "torch==2.14.1" "torchvision==0.29.1"
fi

# open3d-cpu instead of the [open3d] extra's open3d (never both).
stamp="$VENV/.quash-installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  need_space 2500 "quash-plugins' extras (open3d, rerun, transformers, dask, ...)"
  echo "[setup] installing quash-plugins and its extras"
  quiet_pip -e ".[clip,st,rerun,llm,dask,hdf5,plots,dev]" "open3d-cpu>=0.18"
  touch "$stamp"
fi
echo "[setup] ready: $VENV/bin/quash"
