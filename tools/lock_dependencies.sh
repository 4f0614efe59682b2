#!/usr/bin/env bash
# Regenerates requirements.lock: every package torchrl-ahrs and its [test] and [mjx] extras need (CI runs the
# MJX tests), pinned, with sha256 hashes, for CPython 3.11 on linux x86_64 (the project's machines).
# Existing pins are kept (uv prefers
# the versions already in the output file); pass --upgrade or --upgrade-package NAME to move them.
#
# uv runs from a throwaway virtual environment, never the project's. The machine's pip configuration
# lists the local wheel directory (/opt/wheels, holding torch 2.13.0+cpu) and the local mirror indexes
# next to PyPI; they are passed to uv the same way so it locks the files pip will actually install.
# Afterwards tools/check_dependencies.py refuses known-compromised releases.
set -euo pipefail
cd "$(dirname "$0")/.."
TOOL_VENV="${TOOL_VENV:-${TMPDIR:-/tmp}/torchrl_ahrs_lock_tool}"
[ -x "$TOOL_VENV/bin/uv" ] || { python3 -m venv "$TOOL_VENV" && "$TOOL_VENV/bin/pip" install -q uv; }
sources=()
[ -d /opt/wheels ] && sources+=(--find-links /opt/wheels)
for index in /opt/pypi/simple /opt/pypi-more/simple; do
    [ -d "$index" ] && sources+=(--extra-index-url "file://$index")
done
"$TOOL_VENV/bin/uv" pip compile pyproject.toml --extra test --extra mjx \
    --generate-hashes --python-version 3.11 --python-platform x86_64-manylinux_2_28 \
    "${sources[@]}" --index-strategy unsafe-best-match \
    --custom-compile-command "tools/lock_dependencies.sh" \
    -o requirements.lock "$@"
python3 tools/check_dependencies.py requirements.lock
