#!/usr/bin/env bash
# Screenshots a report page with headless Chromium, to check that it renders with every
# image visible: scripts/screenshot.sh out/demo/report.html [out.png] [HEIGHT_PX]
# Installs Chromium (Debian package `chromium`) when missing.
set -euo pipefail
page="${1:?usage: scripts/screenshot.sh REPORT.html [OUT.png] [HEIGHT_PX]}"
png="${2:-${page%.html}.png}"
height="${3:-4000}"
[ -f "$page" ] || { echo "error: $page does not exist" >&2; exit 2; }
if ! command -v chromium >/dev/null 2>&1; then
    sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
    $sudo apt-get install -y -qq --no-install-recommends chromium >/dev/null
fi
chromium --headless --no-sandbox --disable-gpu --hide-scrollbars \
    --window-size="1200,$height" --screenshot="$png" "file://$(realpath "$page")" 2>/dev/null
[ -s "$png" ] || { echo "error: no screenshot written" >&2; exit 1; }
echo "$png"
