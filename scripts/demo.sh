#!/usr/bin/env bash
# The main job: the whole pipeline on the embedded synthetic sequence. Renders a hexapod's
# RGB-D sequence with ground-truth poses and terrain, tracks it with the SLAM, maps
# the terrain (our mapper and the Fankhauser baseline, with ground-truth and with the SLAM's
# poses) and writes out/demo/report.html. Installs what is missing first (scripts/setup.sh).
# Extra arguments go to `stride demo` (e.g. --frames 150, --seed 2, --no-blur).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo run --release --locked --quiet --bin stride -- demo --out out/demo --overwrite "$@"
