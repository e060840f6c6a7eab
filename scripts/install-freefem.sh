#!/usr/bin/env bash
# Installs FreeFEM from Debian's packages when FreeFem++ is missing. Both packages are
# needed: the plugins (gmsh, iovtk) live in libfreefem++.
set -euo pipefail
if command -v FreeFem++ >/dev/null 2>&1 && [ -d /usr/lib/freefem++ ]; then
  exit 0
fi
echo "installing FreeFEM (Debian packages freefem++ libfreefem++)..." >&2
sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq freefem++ libfreefem++ >/dev/null
command -v FreeFem++ >/dev/null || { echo "error: FreeFem++ still missing after apt-get install" >&2; exit 1; }
