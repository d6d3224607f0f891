#!/usr/bin/env bash
# The main job. For now (foundation): evaluate the shared fr1/xyz RGB-D SLAM estimate against
# its ground truth and write a report into out/demo. Extra arguments go to `stride eval ate`.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo build --release --locked --bin stride
data="${STRIDE_DATA:-../shared/data}/trajectories"
target/release/stride eval ate --gt "$data/freiburg1_xyz-groundtruth.txt" \
    --est "$data/freiburg1_xyz-rgbdslam.txt" --align se3 --report out/demo "$@"
echo "report: out/demo/report.html"
