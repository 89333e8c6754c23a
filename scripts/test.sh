#!/usr/bin/env bash
# The README's test command: installs what is missing (idempotent), builds, runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source "${GESTHOR_DEPS:-$HOME/.cache/gesthor}/env.sh"
cargo build --release --workspace --locked
cargo test --release --workspace --locked -- --test-threads="${GESTHOR_TEST_THREADS:-2}"
