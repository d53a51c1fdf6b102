#!/usr/bin/env bash
# Set up a fresh machine: Debian's libLLVM 19 for drjit's LLVM backend (the Debian 14/15 builds
# abort with "Cannot select: fminimum"), then this package with every extra.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! ldconfig -p 2>/dev/null | grep -q 'libLLVM-19\|libLLVM.so.19'; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
    else
        echo "setup: install Debian's libllvm19 (or set DRJIT_LIBLLVM_PATH) for Mitsuba's LLVM variants" >&2
    fi
fi
python3 -m pip install -q -e ".[all]"
