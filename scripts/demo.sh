#!/usr/bin/env bash
# Quick-start step 1: set everything up (see scripts/setup.sh), then run the main job,
#   mcrt demo --output out/demo [extra args...]
# which renders the shipped scenes with each sampler and writes images and a comparison.
# Runs from the repo root, so out/demo (and relative paths in extra args) are relative to it.
# A later --output in the extra args overrides the default.
set -euo pipefail

# shellcheck source=scripts/setup.sh
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
mcrt_setup

cd "$MCRT_ROOT"
log "running: mcrt demo --output out/demo $*"
exec "$MCRT_VENV/bin/mcrt" demo --output out/demo "$@"
