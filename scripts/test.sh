#!/usr/bin/env bash
# Runs every test of the workspace (unit, integration, end-to-end on ../shared/data or
# $STRIDE_DATA) in release mode, after installing what is missing (scripts/setup.sh).
# Extra arguments go to `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo test --workspace --release --locked "$@"
