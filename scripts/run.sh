#!/usr/bin/env bash
# The README's main command: installs what is missing (idempotent), builds, makes the default
# dataset if there is none and the label-free RGB-D encoder (configs/tiny/*; it ships with the
# repository) if it is missing, then trains the embedded default configuration (tiny CPU +Both)
# on the farm and evaluates its last checkpoint on the validation split.
# Extra arguments go to `orchestrator up` (e.g. --workers 4, --seconds 600).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source "${GESTHOR_DEPS:-$HOME/.cache/gesthor}/env.sh"
cargo build --release --workspace --locked
ORCH=target/release/orchestrator
DATA="${GESTHOR_DATASET:-data/gond}"
if [ ! -f "$DATA/manifest.json" ]; then
  "$ORCH" dataset build --out "$DATA"
fi
ENCODER="${GESTHOR_ENCODER:-encoders/contrast64}"
if [ ! -f "$ENCODER.safetensors" ]; then
  # the default's ships with the repository; another is made label-free (dense contrast), about
  # 4–7 minutes on two cores; the same seed gives the same file (sha256 in $ENCODER.json)
  "$ORCH" encoder pretrain --out "$ENCODER" --dataset "$DATA"
fi
RUN="${GESTHOR_RUN_DIR:-runs/default}"
if ls "$RUN"/checkpoints/ckpt-*.safetensors >/dev/null 2>&1; then
  # a second run.sh continues the first run's training instead of starting over
  "$ORCH" up --resume "$RUN" "$@"
else
  "$ORCH" up --run-dir "$RUN" "$@"
fi
# every pass the checkpoint allows, and the pointing check: each program again with another
# room's referencing gesture (what of the arm's direction is read), beside the first turns
"$ORCH" eval --checkpoint "$RUN" --split val --max-programs 500 --out "$RUN/eval/val" \
  --modes normal,blind,rgb_only,depth_only,other_gesture
# the shipped +Both (5M frames) on the same programs, and the two side by side
"$ORCH" eval --checkpoint models/both --split val --max-programs 500 --dataset "$DATA" \
  --out "$RUN/eval/val-shipped-both" --label "shipped +Both (5M)" --modes normal,blind,other_gesture >/dev/null
"$ORCH" eval --compare "$RUN/eval/val" "$RUN/eval/val-shipped-both" --split val --dataset "$DATA"
