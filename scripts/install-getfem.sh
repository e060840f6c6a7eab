#!/usr/bin/env bash
# Installs GetFEM 5.4 (Debian's python3-getfem) when Debian's Python cannot import it. Only
# the cross-check needs it (peer_getfem/peer.py runs under /usr/bin/python3, never in the
# venv); the rest of the harness works without it.
#
#   install-getfem.sh           install when missing
#   install-getfem.sh --check   only say whether it is there: exit 0 if so, 1 if not
#
# The import is tried with `-I` (isolated: no current directory, no PYTHONPATH, no user
# site) from a neutral directory, so that no folder of the checkout, nor anything else beside
# the caller, can pass for the package. PEER_PYTHON names another interpreter (the tests
# point it at one without GetFEM).
set -euo pipefail
peer_python="${PEER_PYTHON:-/usr/bin/python3}"
has_getfem() { (cd / && "$peer_python" -I -c "import getfem, numpy, scipy") >/dev/null 2>&1; }
if has_getfem; then
  exit 0
fi
if [ "${1:-}" = "--check" ]; then
  echo "GetFEM is not importable by $peer_python" >&2
  exit 1
fi
bash "$(dirname "$0")/apt-install.sh" python3-getfem python3-scipy
has_getfem || { echo "error: python3-getfem installed but $peer_python cannot import getfem" >&2; exit 1; }
