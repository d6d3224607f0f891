#!/usr/bin/env bash
# Runs every test of the workspace (unit, integration, end-to-end on ../shared/data or
# $STRIDE_DATA) in release mode, after installing what is missing (scripts/setup.sh).
# Extra arguments go to `cargo test`.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo test --workspace --release --locked "$@"

# The library example, as a user would run it (README: "stride as a library").
data="${STRIDE_DATA:-../shared/data}"
teddy="$data/tum/rgbd_dataset_freiburg3_teddy_200"
if [ -d "$teddy" ]; then
    cargo run --release --locked --example pipeline -- "$teddy" 60
elif [ "${CI:-}" = "true" ]; then
    echo "error: $teddy is missing; the example cannot run" >&2
    exit 1
else
    echo "skipped the example: $teddy is missing"
fi
