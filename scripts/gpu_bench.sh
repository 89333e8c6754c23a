#!/usr/bin/env bash
# The faithful config's throughput on a GPU machine (docs/bench/log.md, "On the H100"), in the order
# the next window needs it: configs/faithful-gpu end to end (rounds of 512 envs in two groups) as
# before, with its frames kept on the GPU (the CUDA import, checked: the script fails without it),
# and timed stage by stage; then the learner's acting and update alone, PyTorch's own trunk and
# transfer, §4.3.2's 20 envs and one group for all. A step starts only while BUDGET_S (default
# 500) seconds have not passed, so one 10-minute command ends with what it measured; a step that
# fails makes the script exit 1 at its end. For a machine with CUDA PyTorch and no Rust: the
# binaries are built elsewhere and found in $GESTHOR_BIN_DIR (default target/release); libtorch is
# the machine's PyTorch; a Vulkan loader carried as Debian packages in .gl/ is unpacked when there.
#
#   GESTHOR_BIN_DIR=.bin bash scripts/gpu_bench.sh OUT_DIR
#
# Everything measured is written to OUT_DIR/gpu-bench.tar (the device returns at most 8 files;
# `tar xf` it into docs/bench/…); the tables are also printed at the end.
#
# The three release binaries, stripped and xz-packed, are about 14 MB (unpacked 48 MB: too much
# beside the work tree for a 64 MiB transfer): `bash scripts/gpu_pack.sh` here makes .pack/ and
# .gl/; there `python3 -m tarfile -e .pack/bins.tar.xz .bin` (the machine has no xz tool of its own
# to rely on), then this script with GESTHOR_BIN_DIR=.bin.
set -uo pipefail
dest=${1:?give the folder the tables go to}
out=$(mktemp -d)
budget=${BUDGET_S:-500}
began=$SECONDS
mkdir -p "$dest"
trap 'tar cf "$dest/gpu-bench.tar" -C "$out" .' EXIT
bin=${GESTHOR_BIN_DIR:-target/release}
export GESTHOR_BIN_DIR=$bin

torch_lib=$(python3 -c "import os, torch; print(os.path.join(os.path.dirname(torch.__file__), 'lib'))") || exit 1
export LD_LIBRARY_PATH=$torch_lib:${LD_LIBRARY_PATH:-}
if [ -d .gl ] && ! ldconfig -p | grep -q libvulkan.so.1; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/gpu.txt"
nproc | tee -a "$out/gpu.txt"

# starts the next step, or says it is skipped (and returns 1) once the budget is spent
step() {
  if (( SECONDS - began > budget )); then echo "== skipped (budget): $*" | tee -a "$out/steps.txt"; return 1; fi
  echo "== $(date -u +%T) $*" | tee -a "$out/steps.txt"
}
# NAME COMMAND...: a step whose failure is written down and fails the script at its end (after
# the other steps have measured what they can)
failed=()
check() {
  local name=$1; shift
  step "$name" || return 0
  "$@" || { echo "== FAILED: $name" | tee -a "$out/steps.txt"; failed+=("$name"); }
}

echo "== $(date -u +%T) dataset" | tee -a "$out/steps.txt"
[ -f data/gond/manifest.json ] || "$bin/orchestrator" dataset build --out data/gond >/dev/null || exit 1
# random torchvision weights, frozen: the same work as ImageNet's (none can be downloaded there)
mkdir -p data/weights
python3 -c "import torch, torchvision; torch.save(torchvision.models.resnet18().state_dict(), 'data/weights/resnet18-imagenet.pth')" || exit 1

# a short first forward and update: CUDA loads its kernels on first use (on a fresh machine a first
# update took 6.4 s where later ones took 0.9), which must not land in the first run's figures
step warm-up && timeout 90 "$bin/learner" bench --faithful --act 512 --update 256x2 --reps 1 >/dev/null 2>&1
nvidia-smi dmon -s u -d 1 > "$out/dmon.txt" 2>&1 &
dmon=$!
train() { # NAME, then bench train's extra arguments
  local name=$1; shift
  timeout 150 "$bin/orchestrator" bench train --config configs/faithful-gpu/both.toml --workers 16 --frames 150000 \
    --out "/tmp/bench-$name" --table "$out/train-$name.md" "$@" 2>&1 | grep -v "^\[bench\] [0-9]" | tail -3
}
check "train faithful-gpu 16x32, two groups" train 512
# the frames kept on the GPU: drawn into memory each worker exports, imported by CUDA in the
# learner; no frame crosses the host. The import's lines are kept; a run that did not import
# (or a CUDA call that failed) fails the script.
device_frames() {
  train 512-device --set env.frames=device || return 1
  grep -h "imported\|frames on the device\|Error\|error" /tmp/bench-512-device/run/logs/learner.log \
    /tmp/bench-512-device/run/logs/worker-0.log 2>/dev/null | head -5 | tee "$out/device-frames.txt"
  grep -q "imported" "$out/device-frames.txt" && ! grep -qi "error" "$out/device-frames.txt"
}
check "train faithful-gpu 16x32, two groups, frames on the device" device_frames
# the update learned on a thread while the next rollout is collected (policy lag 1): its ratio to
# the first run says whether ppo.overlap_update pays on this card
check "train faithful-gpu 16x32, two groups, update overlapped" train 512-overlap --set ppo.overlap_update=true
# acting and the update stage by stage: the learner waits for the GPU after each stage, so this
# run is slower than the first; its last table says which stage of the inference share to cut
check "train faithful-gpu 16x32, two groups, by stage" train 512-stages --stages
learner_bench() {
  timeout 150 "$bin/learner" bench --faithful --act 20,64,128,256,512 --update 20x2,256x8,256x4,256x2 --reps 5 2>&1 |
    tee "$out/learner-bench.txt"
}
check "learner bench" learner_bench
ceilings() { timeout 60 python3 scripts/gpu_trunk_ceiling.py 256 512 2>&1 | tee "$out/ceiling.txt"; }
check "trunk and transfer ceilings" ceilings
# §4.3.2's 20 envs (the command of the 1,629 frames/s), and one round for all 512
train_20() {
  timeout 120 "$bin/orchestrator" bench train --config configs/faithful/both.toml --workers 5 \
    --frames 30000 --out /tmp/bench-20 --table "$out/train-20.md" 2>&1 | grep -v "^\[bench\] [0-9]" | tail -3
}
check "train 5x4" train_20
check "train faithful-gpu 16x32, one group" train 512-g1 --set ppo.env_groups=1
echo "== $(date -u +%T) done" >> "$out/steps.txt"
kill $dmon 2>/dev/null
cat "$out"/train-*.md
if ((${#failed[@]})); then
  printf '== failed: %s\n' "${failed[@]}" | tee -a "$out/steps.txt"
  exit 1
fi
