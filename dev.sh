#!/usr/bin/env bash
# Shape from Tracing developer entry point.
#   ./dev.sh demo   set up .venv, synthesise the built-in object, reconstruct it, print metrics
#   ./dev.sh test   set up .venv and run the whole test suite
#   ./dev.sh setup  only set up .venv (fast when requirements.txt has not changed)
set -euo pipefail
cd "$(dirname "$0")"

find_python() {
    for candidate in "${SFT_BOOTSTRAP_PYTHON:-}" python3.11 python3; do
        [ -n "$candidate" ] || continue
        if command -v "$candidate" >/dev/null 2>&1 &&
            "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
            echo "$candidate"
            return
        fi
    done
    echo "error: Python 3.11 is required (the bpy 5.0.1 wheel is cp311); set SFT_BOOTSTRAP_PYTHON" >&2
    exit 2
}

setup() {
    local stamp=.venv/.requirements.sha256 want
    want=$(cat requirements.txt backend/requirements.txt | sha256sum | cut -d' ' -f1)
    if [ -x .venv/bin/python ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
        return
    fi
    echo "setting up .venv (first run downloads about 1 GB of wheels)..."
    [ -x .venv/bin/python ] || "$(find_python)" -m venv .venv
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -r requirements.txt
    .venv/bin/python -c 'pass'  # first start lets karellen-llvm-core create its libLLVM links
    .venv/bin/python -m backend check >/dev/null || { .venv/bin/python -m backend check; exit 1; }
    echo "$want" >"$stamp"
}

case "${1:-}" in
    setup) setup ;;
    demo) setup; shift; exec .venv/bin/python -m backend demo "$@" ;;
    test) setup; shift; exec .venv/bin/python -m pytest tests "$@" ;;
    *) sed -n '2,5p' "$0"; exit 2 ;;
esac
