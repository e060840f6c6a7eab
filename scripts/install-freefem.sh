#!/usr/bin/env bash
# Installs FreeFEM from Debian's packages when FreeFem++ is missing. Both packages are
# needed: the plugins (gmsh, iovtk) live in libfreefem++.
set -euo pipefail
if command -v FreeFem++ >/dev/null 2>&1 && [ -d /usr/lib/freefem++ ]; then
  exit 0
fi
bash "$(dirname "$0")/apt-install.sh" freefem++ libfreefem++
command -v FreeFem++ >/dev/null || { echo "error: FreeFem++ still missing after apt-get install" >&2; exit 1; }
