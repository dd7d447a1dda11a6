#!/usr/bin/env bash
# Quick-start step 2: set everything up (see scripts/setup.sh), lint (ruff), type-check (mypy,
# configured in pyproject.toml), check the layers (lint-imports, contracts in pyproject.toml),
# then run the test suite,
#   python -m pytest -q [extra args...]      e.g. bash scripts/test.sh -x -k sampler
# `--fast` first: the everyday tier, -m "not slow" -n 2 (no end-to-end or long tests, two
# workers; about a minute on 2 cores). Without arguments (CI): every test, the ones not marked
# serial on two workers, then the serial ones (conftest.py's SERIAL_MODULES) in one process.
# A lint, type or layer error fails the run before any test starts.
# CI runs exactly this script (.ci/run).
set -euo pipefail

# shellcheck source=scripts/setup.sh
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
mcrt_setup

cd "$MCRT_ROOT"
# Tests may plot: never try to open a window (CI has no display).
export MPLBACKEND=Agg
# Chromium is installed: the report viewer's browser test must run, not skip.
if (( MCRT_BROWSER_READY )); then export MCRT_REQUIRE_BROWSER=1; fi

log "running: ruff check mcrt tests benchmarks scripts"
"$MCRT_VENV/bin/ruff" check mcrt tests benchmarks scripts \
    || { err "ruff found problems (see above; many are fixed by: .venv/bin/ruff check --fix)"; exit 1; }
log "running: mypy (files and settings in pyproject.toml)"
"$MCRT_VENV/bin/mypy" || { err "mypy found type errors (see above)"; exit 1; }
log "running: lint-imports (layer contracts in pyproject.toml, docs/architecture.md)"
"$MCRT_VENV/bin/lint-imports" \
    || { err "an import breaks a layer contract (see above and docs/architecture.md)"; exit 1; }

if [[ "${1:-}" == "--fast" ]]; then  # the everyday tier, on two pytest workers
    shift
    set -- -m "not slow" -n 2 "$@"
elif (( $# == 0 )); then
    # The whole suite (CI): every test not marked serial on two workers (work stealing
    # balances the long ones), then the serial ones (which kill processes and cluster
    # workers at moments they pick, or cap memory) one at a time.
    log "running: python -m pytest -q -m 'not serial' -n 2 --dist worksteal"
    "$MCRT_VENV/bin/python" -m pytest -q -m "not serial" -n 2 --dist worksteal
    set -- -m serial
fi
log "running: python -m pytest -q $*"
exec "$MCRT_VENV/bin/python" -m pytest -q "$@"
