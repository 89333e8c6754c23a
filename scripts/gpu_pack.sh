#!/usr/bin/env bash
# What a GPU window carries, made here (the GPU machine has PyTorch but no Rust): the three release
# binaries, stripped and xz-packed into .pack/bins.tar.xz (about 16 MB), and the Vulkan loader as
# Debian packages in .gl/ (scripts/gpu_bench.sh unpacks them where the machine lacks one). Then one
# command on the GPU machine, carrying .pack and .gl:
#   python3 -m tarfile -e .pack/bins.tar.xz .bin && GESTHOR_BIN_DIR=.bin bash scripts/gpu_bench.sh "$OUT"
set -euo pipefail
cd "$(dirname "$0")/.."
[ -f "$HOME/.cache/gesthor/env.sh" ] && source "$HOME/.cache/gesthor/env.sh"
cargo build --release --locked --workspace
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for b in orchestrator learner worker; do
  strip -o "$tmp/$b" "target/release/$b"
done
mkdir -p .pack .gl
tar cJf .pack/bins.tar.xz -C "$tmp" orchestrator learner worker
(cd .gl && rm -f ./*.deb && apt-get download libvulkan1 >/dev/null)
du -sh .pack/bins.tar.xz .gl
