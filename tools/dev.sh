#!/usr/bin/env bash
# One entry point for set-up, tests and demo renders.  Creates .venv/ (pinned requirements,
# bpy 5.0.1 from PyPI) when it is missing, builds the C kernels, then runs the sub-command:
#   tools/dev.sh test [pytest args]   run the test suite, its files shared between
#                                     MPP_TEST_WORKERS (default 2) pytest-xdist workers;
#                                     MPP_TEST_WORKERS=0 runs them in this one process
#   tools/dev.sh demo [args]          render the bundled demo scene (out/demo.exr, .png)
#   tools/dev.sh py ARGS              run the venv's python
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
PY="${PYTHON:-python3.11}"
command -v "$PY" >/dev/null 2>&1 || PY=python3
if [ ! -x .venv/bin/python ] || ! cmp -s requirements.txt .venv/.requirements 2>/dev/null; then
    echo "[dev] creating .venv with $("$PY" --version)" >&2
    "$PY" -m venv .venv
    .venv/bin/python -m pip install -q --upgrade pip >&2
    .venv/bin/python -m pip install -q -r requirements.txt >&2
    cp requirements.txt .venv/.requirements
fi
# (Re)build the C kernels when any source or header (mpp_render/csrc/) is newer than the module.
SO=$(ls mpp_render/_kernels*.so 2>/dev/null | head -1 || true)
stale=""
if [ -z "$SO" ] || [ setup.py -nt "$SO" ]; then
    stale=1
else
    for f in mpp_render/csrc/*.c mpp_render/csrc/*.h; do
        if [ "$f" -nt "$SO" ]; then stale=1; break; fi
    done
fi
if [ -n "$stale" ]; then
    echo "[dev] building C kernels" >&2
    .venv/bin/python setup.py -q build_ext --inplace >&2
fi
cmd="${1:-test}"; shift || true
case "$cmd" in
    test) exec .venv/bin/python -m pytest -q -n "${MPP_TEST_WORKERS:-2}" --dist loadfile \
              --no-loadscope-reorder "$@" ;;
    demo) exec .venv/bin/python -m mpp_render demo "$@" ;;
    py)   exec .venv/bin/python "$@" ;;
    *) echo "usage: tools/dev.sh test|demo|py ..." >&2; exit 2 ;;
esac
