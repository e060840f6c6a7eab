#!/usr/bin/env bash
# Installs GetFEM 5.4 (Debian's python3-getfem) when Debian's Python cannot import it. Only
# the cross-check needs it (getfem/peer.py runs under /usr/bin/python3, never in the venv);
# the rest of the harness works without it.
set -euo pipefail
if /usr/bin/python3 -c "import getfem" >/dev/null 2>&1; then
  exit 0
fi
bash "$(dirname "$0")/apt-install.sh" python3-getfem
/usr/bin/python3 -c "import getfem" || { echo "error: python3-getfem installed but /usr/bin/python3 cannot import getfem" >&2; exit 1; }
