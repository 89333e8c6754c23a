#!/usr/bin/env bash
# The faithful config's throughput on a GPU machine (BENCHMARKS.md, "On the H100"): the learner's
# acting and update at several batch sizes, PyTorch's own trunk and transfer for comparison, then
# `bench train` end to end at §4.3.2's 20 envs and at configs/faithful-gpu's rounds of 512 envs
# (one group, two groups, two groups timed stage by stage). For a machine with CUDA PyTorch and no
# Rust: the binaries are built elsewhere and found in $GESTHOR_BIN_DIR (default target/release);
# libtorch is the machine's PyTorch; a Vulkan loader carried as Debian packages in .gl/ is unpacked
# when there.
#
#   GESTHOR_BIN_DIR=.bin bash scripts/gpu_bench.sh OUT_DIR
#
# The three release binaries, stripped and xz-packed, are about 14 MB (unpacked 48 MB: too much
# beside the work tree for a 64 MiB transfer): `bash scripts/gpu_pack.sh` here makes .pack/ and
# .gl/; there `python3 -m tarfile -e .pack/bins.tar.xz .bin` (the machine has no xz tool of its own
# to rely on), then this script with GESTHOR_BIN_DIR=.bin.
set -uo pipefail
out=${1:?give the folder the tables go to}
mkdir -p "$out"
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

step() { echo "== $(date -u +%T) $*" | tee -a "$out/steps.txt"; }

step dataset
"$bin/orchestrator" dataset build --out data/gond >/dev/null || exit 1
# random torchvision weights, frozen: the same work as ImageNet's (none can be downloaded there)
mkdir -p data/weights
python3 -c "import torch, torchvision; torch.save(torchvision.models.resnet18().state_dict(), 'data/weights/resnet18-imagenet.pth')" || exit 1

step learner bench
timeout 150 "$bin/learner" bench --faithful --act 20,64,128,256,512 --update 20x2,256x8,256x4,256x2 --reps 5 2>&1 | tee "$out/learner-bench.txt"

step trunk and transfer ceilings
timeout 60 python3 scripts/gpu_trunk_ceiling.py 256 512 2>&1 | tee "$out/ceiling.txt"

# end to end: §4.3.2's 20 envs (the command of the 1,629 frames/s), and configs/faithful-gpu
# (rounds of 512 envs) with one round for all and with its two groups of workers in turn
nvidia-smi dmon -s u -d 1 > "$out/dmon.txt" 2>&1 &
dmon=$!
step train 5x4
timeout 120 "$bin/orchestrator" bench train --config configs/faithful/both.toml --workers 5 --frames 30000 \
  --out /tmp/bench-20 --table "$out/train-20.md" 2>&1 | grep -v "^\[bench\] [0-9]" | tail -3
step train faithful-gpu 16x32, one group
timeout 150 "$bin/orchestrator" bench train --config configs/faithful-gpu/both.toml --workers 16 --frames 150000 \
  --set ppo.env_groups=1 --out /tmp/bench-512-g1 --table "$out/train-512-g1.md" 2>&1 | grep -v "^\[bench\] [0-9]" | tail -3
step train faithful-gpu 16x32, two groups
timeout 150 "$bin/orchestrator" bench train --config configs/faithful-gpu/both.toml --workers 16 --frames 150000 \
  --out /tmp/bench-512 --table "$out/train-512.md" 2>&1 | grep -v "^\[bench\] [0-9]" | tail -3
# the same with the frames kept on the GPU (issue 52): drawn into memory each worker exports,
# imported by CUDA in the learner; no frame crosses the host
step train faithful-gpu 16x32, two groups, frames on the device
timeout 150 "$bin/orchestrator" bench train --config configs/faithful-gpu/both.toml --workers 16 --frames 150000 \
  --set env.frames=device --out /tmp/bench-512-device --table "$out/train-512-device.md" 2>&1 \
  | grep -v "^\[bench\] [0-9]" | tail -3
grep -h "imported\|frames on the device\|Error\|error" /tmp/bench-512-device/run/logs/learner.log \
  /tmp/bench-512-device/run/logs/worker-0.log 2>/dev/null | head -5 | tee "$out/device-frames.txt"
# two groups again, acting and the update timed stage by stage (issue 52): the learner waits for
# the GPU after each stage, so this run is slower than the one above; its last table says which
# stage of the inference share to cut
step train faithful-gpu 16x32, two groups, by stage
timeout 150 "$bin/orchestrator" bench train --config configs/faithful-gpu/both.toml --workers 16 --frames 150000 \
  --stages --out /tmp/bench-512-stages --table "$out/train-512-stages.md" 2>&1 | grep -v "^\[bench\] [0-9]" | tail -3
step done
kill $dmon 2>/dev/null
cat "$out"/train-*.md
