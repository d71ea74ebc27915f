#!/usr/bin/env bash
# README command 2: set up (idempotent) and run the whole test suite, MPI tests included.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/run/setup.sh" --test
source "$root/run/env.sh"
cd "$root"
exec .venv/bin/python -m pytest -q "$@"
