#!/usr/bin/env bash
# The README's test command: installs what is missing (idempotent), builds, runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# structure first (a second): the checker's own cases, then no import cycle between files of a
# crate, no oversized file, no broken Markdown link
selftest=$(python3 scripts/check_structure.py --self-test 2>&1) || { echo "$selftest"; exit 1; }
python3 scripts/check_structure.py
source "${GESTHOR_DEPS:-$HOME/.cache/gesthor}/env.sh"
# `cargo test` reuses every dependency `cargo build` compiled only if their features agree
bash scripts/check_features.sh
cargo build --release --workspace --locked
cargo test --release --workspace --locked -- --test-threads="${GESTHOR_TEST_THREADS:-2}"
