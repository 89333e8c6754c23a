#!/usr/bin/env bash
# `cargo build` and `cargo test` share a compiled dependency only where both resolve it with the
# same features. The test build adds dev-dependencies (proptest, criterion), whose features on
# shared crates (getrandom, regex-automata, …) would make cargo compile those crates, and
# everything above them (tracing-subscriber, zenoh, farm, worker, orchestrator), a second time.
# farm/Cargo.toml names those features for the normal build; this says when that list is stale.
set -euo pipefail
cd "$(dirname "$0")/.."
features() {
  cargo tree --workspace --locked --prefix none -f '{p} {f}' -e "$1" | sed 's/ (\*)$//' | sort -u
}
build=$(features normal,build)
test=$(features normal,build,dev)
changed=$(comm -23 <(echo "$build") <(echo "$test"))
if [ -n "$changed" ]; then
  echo "scripts/check_features.sh: \`cargo test\` resolves these dependencies with other features than"
  echo "\`cargo build\` (name the test build's under farm/Cargo.toml's feature-only dependencies):"
  echo "$changed" | sed 's/^/  cargo build: /'
  echo "$test" | grep -F -f <(echo "$changed" | cut -d' ' -f1,2) | sed 's/^/  cargo test:  /'
  exit 1
fi
