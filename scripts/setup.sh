#!/usr/bin/env bash
# Installs what GesTHOR-RS needs on a fresh Debian/Ubuntu machine; safe to run again.
#   - Mesa lavapipe + Vulkan loader: wgpu renders headless on the CPU
#   - libtorch 2.11.0 (from the PyPI wheel, no Python needed at run time) for tch 0.24
#   - numpy, iceoryx2 0.10.0, tensorboard 2.21.0, gymnasium 1.4.0, cyclonedds 11.0.1 for the Python tests (tests/python)
#   - MediaPipe 0.10.14 (with its landmark models) for `orchestrator gesture capture`
#   - Chromium and its WebDriver, for the browser test of `orchestrator live`
# Prints the environment to source as its last lines; `source scripts/env.sh` does that for you.
set -euo pipefail

DEPS="${GESTHOR_DEPS:-$HOME/.cache/gesthor}"
TORCH_VERSION=2.11.0
mkdir -p "$DEPS"

log() { printf '[setup] %s\n' "$*" >&2; }

need_apt=()
for pkg in mesa-vulkan-drivers libvulkan1 python3-pip chromium chromium-driver; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need_apt+=("$pkg")
done
if ((${#need_apt[@]})); then
  log "apt-get install ${need_apt[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
fi

PY=python3
export PIP_ROOT_USER_ACTION=ignore  # pip installs into our own folders, not the system
# Older pips match a wheel's platform tag exactly, so name every manylinux level the wheels use.
PLATFORMS=""
for n in 17 24 25 26 27 28; do PLATFORMS+=" --platform manylinux_2_${n}_x86_64"; done
PLATFORMS+=" --platform manylinux2014_x86_64"
TORCH_DIR="$DEPS/torch-$TORCH_VERSION"
if [ ! -f "$TORCH_DIR/.complete" ]; then
  log "downloading libtorch $TORCH_VERSION (PyPI wheel, about 1.2 GB) into $TORCH_DIR"
  rm -rf "$TORCH_DIR.partial"
  $PY -m pip install -q --disable-pip-version-check --no-deps --only-binary=:all: \
    --python-version 3.12 --implementation cp $PLATFORMS \
    --target "$TORCH_DIR.partial" \
    "torch==$TORCH_VERSION" nvidia-cuda-runtime==13.0.96 nvidia-cuda-cupti==13.0.85
  rm -rf "$TORCH_DIR"
  mv "$TORCH_DIR.partial" "$TORCH_DIR"
  touch "$TORCH_DIR/.complete"
fi

PYDIR="$DEPS/python"
# The marker holds the requirements it was made from: a changed list installs afresh.
PY_REQS="numpy iceoryx2==0.10.0 tensorboard==2.21.0 gymnasium==1.4.0 cyclonedds==11.0.1"
if [ "$(cat "$PYDIR/.complete" 2>/dev/null)" != "$PY_REQS" ]; then
  log "installing $PY_REQS (Python) into $PYDIR"
  rm -rf "$PYDIR"
  # shellcheck disable=SC2086 # one word per requirement
  $PY -m pip install -q --disable-pip-version-check --only-binary=:all: --target "$PYDIR" $PY_REQS
  echo "$PY_REQS" > "$PYDIR/.complete"
fi

# MediaPipe Holistic for `orchestrator gesture capture`: 0.10.14 is the newest wheel that ships its
# landmark models (pose, hands) inside, so capture runs offline. Its own requirements pull JAX,
# which capture does not use, so what it imports is pinned here, installed without resolving
# (numpy 1: the wheel is built against it), in a folder apart from the Python packages above.
CAPDIR="$DEPS/capture"
CAP_REQS="mediapipe==0.10.14 absl-py==2.1.0 attrs==24.2.0 flatbuffers==24.3.25 protobuf==4.25.5 numpy==1.26.4
  opencv-python-headless==4.10.0.84 matplotlib==3.9.2 contourpy==1.3.0 cycler==0.12.1 fonttools==4.54.1
  kiwisolver==1.4.7 packaging==24.1 pillow==10.4.0 pyparsing==3.1.4 python-dateutil==2.9.0.post0 six==1.16.0"
if [ "$(cat "$CAPDIR/.complete" 2>/dev/null)" != "$CAP_REQS" ]; then
  log "installing MediaPipe 0.10.14 (landmark models for gesture capture) into $CAPDIR"
  rm -rf "$CAPDIR"
  # shellcheck disable=SC2086 # one word per requirement
  $PY -m pip install -q --disable-pip-version-check --only-binary=:all: --no-deps --target "$CAPDIR" $CAP_REQS
  echo "$CAP_REQS" > "$CAPDIR/.complete"
fi

cat > "$DEPS/env.sh" <<ENV
export LIBTORCH="$TORCH_DIR/torch"
export LIBTORCH_BYPASS_VERSION_CHECK=0
export LD_LIBRARY_PATH="$TORCH_DIR/torch/lib\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
export PYTHONPATH="$PYDIR\${PYTHONPATH:+:\$PYTHONPATH}"
# the landmark model of gesture capture, apart (it needs numpy 1)
export GESTHOR_CAPTURE_PATH="$CAPDIR"
# mesa-vulkan-drivers (lavapipe) and the Python packages are installed above: tests that render
# must find an adapter, tests that read with Python must find their packages
export GESTHOR_ADAPTER_REQUIRED=1
export GESTHOR_PYTHON_REQUIRED=1
# chromium and chromium-driver are installed above: the live page's browser test must run
export GESTHOR_BROWSER_REQUIRED=1
ENV
log "ready; environment in $DEPS/env.sh"
