#!/usr/bin/env bash
# Installs what stride needs to build, when missing, on Debian/Ubuntu:
#   - system packages: a C toolchain, pkg-config, clang/libclang (for the opencv crate's
#     binding generator) and OpenCV 4 development files (libopencv-dev);
#   - a Rust toolchain (via rustup) if cargo is not on PATH.
# Safe to run repeatedly: it only installs what is missing. Meant to be sourced by the other
# scripts (it exports PATH), but also works when run directly.

stride_setup() {
    local pkgs=(build-essential pkg-config clang libclang-dev libopencv-dev ca-certificates curl)
    local missing=() p
    if command -v dpkg-query >/dev/null 2>&1; then
        for p in "${pkgs[@]}"; do
            dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
        done
    else
        echo "stride setup: not a Debian/Ubuntu system; install the equivalents of: ${pkgs[*]}" >&2
    fi
    if ((${#missing[@]})); then
        local sudo=""
        if [ "$(id -u)" -ne 0 ]; then
            if command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
                echo "stride setup: need root or sudo to install: ${missing[*]}" >&2
                return 1
            fi
        fi
        echo "stride setup: installing ${missing[*]} (about a minute, once)" >&2
        $sudo apt-get update -qq || return 1
        DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null || return 1
    fi
    if ! command -v cargo >/dev/null 2>&1; then
        if [ ! -x "$HOME/.cargo/bin/cargo" ]; then
            echo "stride setup: installing the Rust toolchain with rustup" >&2
            curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs \
                | sh -s -- -y --profile minimal --component rustfmt,clippy >/dev/null || {
                echo "stride setup: could not install Rust; get it from https://rustup.rs" >&2
                return 1
            }
        fi
        export PATH="$HOME/.cargo/bin:$PATH"
    fi
}

if [[ "${BASH_SOURCE[0]}" == "$0" ]]; then
    set -euo pipefail
    stride_setup
else
    stride_setup || return 1
fi
