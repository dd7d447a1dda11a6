#!/usr/bin/env bash
# Quick-start step 2: set everything up (see scripts/setup.sh), then run the test suite,
#   python -m pytest -q [extra args...]      e.g. bash scripts/test.sh -m "not slow" -x
# CI runs exactly this script (.ci/run).
set -euo pipefail

# shellcheck source=scripts/setup.sh
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
mcrt_setup

cd "$MCRT_ROOT"
# Tests may plot: never try to open a window (CI has no display).
export MPLBACKEND=Agg
log "running: python -m pytest -q $*"
exec "$MCRT_VENV/bin/python" -m pytest -q "$@"
