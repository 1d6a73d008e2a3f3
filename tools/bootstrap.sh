#!/usr/bin/env bash
# Installs what `make test` and `make demo` need on a fresh Debian machine:
# the AVR toolchain and simavr (Debian packages), gcc and the Python headers for the fast pipeline's
# C kernel, and a virtualenv with the Python packages.
# Idempotent: it only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

DEBS=(gcc-avr avr-libc simavr libsimavr-dev python3-venv python3-dev make gcc pkg-config)
missing=()
for p in "${DEBS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "bootstrap: installing Debian packages: ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "bootstrap: creating .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.installed
# reinstalled when the package's description or the sources of its compiled kernel
# (device/vision/columns/*.c and *.h, built in place by setup.py) changed
kernel_changed() {
  local f
  for f in device/vision/columns/*.c device/vision/columns/*.h; do
    [ "$f" -nt "$stamp" ] && return 0
  done
  return 1
}
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ setup.py -nt "$stamp" ] || kernel_changed \
   || ! ls device/vision/_columns*.so >/dev/null 2>&1; then
  echo "bootstrap: installing Python packages into .venv"
  .venv/bin/pip install -q --upgrade pip >/dev/null
  .venv/bin/pip install -q -e ".[device,ros,ros2,test]"
  # the kernel's build is optional for pip (a robot installing only the host SDK needs no
  # compiler), not for the device: say so here rather than in every test
  .venv/bin/python -c "import device.vision._columns" || {
    echo "bootstrap: the fast pipeline's C kernel (device/vision/columns) did not build; see pip's output above" >&2
    exit 1; }
  touch "$stamp"
fi
