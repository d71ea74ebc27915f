#!/usr/bin/env bash
# Set amfe up on Debian 12: system PETSc/MPI/h5py, a venv that sees them, the package.
# Idempotent: a second run only checks and returns.
#   bash run/setup.sh [--test]     (--test also installs the test extras)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

# libopenblas0-pthread: an optimised BLAS for MUMPS and scipy (Debian installs the reference one).
# gcc, libc6-dev: amfe's C kernels, built on first use (amfe/model/native.py).
pkgs="petsc-dev python3-petsc4py python3-mpi4py openmpi-bin python3-h5py python3-scipy python3-matplotlib python3-venv python3-pip libopenblas0-pthread gcc libc6-dev"
missing=""
for p in $pkgs; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
    if [ "$(id -u)" -ne 0 ]; then
        echo "amfe set-up: missing Debian packages:$missing" >&2
        echo "Run as root, then run this command again:" >&2
        echo "  apt-get update && apt-get install -y$missing" >&2
        exit 1
    fi
    echo "amfe set-up: installing$missing"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null
fi

# Debian's python3, so the venv sees Debian's petsc4py/mpi4py/h5py/scipy.
if [ ! -x .venv/bin/python ]; then
    /usr/bin/python3 -m venv --system-site-packages .venv
fi
extras=""
[ "${1:-}" = "--test" ] && extras="[test]"
stamp=".venv/.amfe-installed$extras"
want="$(sha256sum pyproject.toml | cut -c1-64)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    # (grep drops this machine's pip-config noise about absent local package folders)
    .venv/bin/python -m pip install -q --disable-pip-version-check -e ".$extras" 2>&1 \
        | { grep -v "^WARNING: Location 'file:" || true; }
    echo "$want" > "$stamp"
fi
