#!/usr/bin/env bash
# (Re)creates the project venv from pyproject.toml's pinned versions: a fresh venv each
# time, so a removed or downgraded pin does not linger. Usage: make-venv.sh PYTHON VENV
set -euo pipefail
python="$1"
venv="$2"
# Debian splits venv/ensurepip out of python3 itself.
if ! (cd / && "$python" -I -c "import ensurepip, venv") >/dev/null 2>&1; then
  bash "$(dirname "$0")/apt-install.sh" "python$("$python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')-venv"
fi
rm -rf "$venv"
"$python" -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip
"$venv/bin/python" -m pip install -q -e ".[cluster]"
touch "$venv/.installed"
