#!/usr/bin/env bash
# The pipelines on 64-bit ARM against x86-64: the fast pipeline's C kernel cross-built for aarch64
# (as pip builds it on a Raspberry Pi: setup.py's build_ext run by an aarch64 Python with the
# build-system's setuptools from pyproject.toml, so with setup.py's -O3 -ffp-contract=off) and
# every pipeline variant run under qemu-user on the golden scenes (tools/golden_scenes.py), and
# the device's pipeline on its moving ones, compared with the same on x86-64: rows, statuses and
# points bit for bit, those of the moving scenes within bounds (tools/arm_check.py says what is
# compared how, and why).
#
#   tools/arm_check.sh            # after `make bootstrap`; exits 0 when the outputs agree
#
# Not part of `make test`: it installs gcc-aarch64-linux-gnu, its C library's headers
# (libc6-dev-arm64-cross: only a Recommends of the compiler, which --no-install-recommends leaves
# out) and qemu-user (Debian packages, ~200 MB), adds arm64 to dpkg's architectures to download
# (not install) Debian's aarch64 Python 3.11 runtime into build/arm/sysroot, downloads the aarch64
# wheels of the .venv's numpy and OpenCV (~60 MB) into build/arm/site and the build-system's
# setuptools into build/arm/build-site, and runs for tens of minutes under emulation.
# Nothing is installed for arm64: the host's packages are not touched beyond the three above.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=build/arm
SYSROOT=$PWD/$OUT/sysroot
BUILD_SITE=$PWD/$OUT/build-site
[ -x .venv/bin/python ] || { echo "arm_check: run \`make bootstrap\` first"; exit 1; }
SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"

# 1. the cross compiler, its C library and the user-mode emulator (host packages)
missing=()
for p in gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "arm_check: installing ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# 2. Debian's aarch64 Python 3.11, unpacked into a private sysroot for qemu -L
RUNTIME=(libc6 libgcc-s1 libstdc++6 libgomp1 zlib1g libexpat1 libffi8 libbz2-1.0 liblzma5 libcrypt1 libssl3
         libuuid1 libsqlite3-0 libncursesw6 libtinfo6 libreadline8 libdb5.3 libnsl2 libtirpc3
         libpython3.11-minimal libpython3.11-stdlib libpython3.11 libpython3.11-dev python3.11-minimal)
if [ ! -x $SYSROOT/usr/bin/python3.11 ]; then
  dpkg --print-foreign-architectures | grep -qx arm64 || { $SUDO dpkg --add-architecture arm64; $SUDO apt-get update -qq; }
  mkdir -p $OUT/debs
  (cd $OUT/debs && apt-get download -qq "${RUNTIME[@]/%/:arm64}")
  for deb in $OUT/debs/*.deb; do dpkg-deb -x "$deb" $SYSROOT; done
fi
PYARM=(qemu-aarch64 -L "$SYSROOT" "$SYSROOT/usr/bin/python3.11")

# 3. the aarch64 wheels of the numpy and OpenCV versions in .venv, and the build-system's setuptools
#    (pyproject.toml: >= 77, for the SPDX license; bookworm's is 66), which pip installs into the
#    build's isolated environment on a Pi (README "On the Pi", "Install")
if [ ! -d $OUT/site/numpy ]; then
  wanted=$(.venv/bin/python -c "import importlib.metadata as m; print(*(f'{d}=={m.version(d)}' for d in ('numpy', 'opencv-contrib-python-headless')))")
  .venv/bin/pip download -q --no-deps --only-binary=:all: --python-version 3.11 --implementation cp --abi cp311 \
    --platform manylinux2014_aarch64 --platform manylinux_2_28_aarch64 -d $OUT/wheels $wanted
  for whl in $OUT/wheels/*.whl; do .venv/bin/python -m zipfile -e "$whl" $OUT/site; done
fi

if [ ! -d $BUILD_SITE/setuptools ]; then
  mapfile -t requires < <(.venv/bin/python -c "import tomllib; print(*tomllib.load(open('pyproject.toml', 'rb'))['build-system']['requires'], sep='\n')")
  .venv/bin/pip download -q --no-deps --only-binary=:all: -d $OUT/build-wheels "${requires[@]}"
  for whl in $OUT/build-wheels/*.whl; do .venv/bin/python -m zipfile -e "$whl" $BUILD_SITE; done
fi

# 4. the package's sources, and the kernel built for aarch64 by setup.py (the gcc it starts is the
#    host's cross compiler, the aarch64 Python's LDSHARED; its headers are the sysroot's)
rm -rf $OUT/src && mkdir -p $OUT/src
tar -c --exclude=__pycache__ --exclude='*.so' setup.py pyproject.toml README.md device protocol host_sdk | tar -x -C $OUT/src
(cd $OUT/src && CFLAGS="-I$SYSROOT/usr/include/python3.11 -I$SYSROOT/usr/include" PYTHONPATH=$BUILD_SITE \
   "${PYARM[@]}" setup.py -q build_ext --inplace 2>&1 | grep -v -e Beta -e warnings.warn || true)
file $OUT/src/device/vision/_columns.cpython-311-aarch64-linux-gnu.so | grep -q "ARM aarch64" \
  || { echo "arm_check: the aarch64 kernel was not built"; exit 1; }

# 5. frames and x86-64 output, the aarch64 output, the comparison
.venv/bin/python tools/arm_check.py frames $OUT
PYTHONPATH=$OUT/src:$OUT/site "${PYARM[@]}" tools/arm_check.py run $OUT
.venv/bin/python tools/arm_check.py compare $OUT
