#!/usr/bin/env bash
# apt-get install the given Debian packages, as root or through sudo.
set -euo pipefail
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "error: need root or sudo to install: $*" >&2; exit 1; }
  sudo="sudo"
fi
echo "installing Debian packages: $* ..." >&2
# One `apt-get update` per set-up: skipped when the package lists are less than an hour old.
if [ -z "$(find /var/lib/apt/lists -maxdepth 1 -name '*Packages*' -mmin -60 2>/dev/null | head -1)" ]; then
  $sudo apt-get update -qq
fi
$sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
