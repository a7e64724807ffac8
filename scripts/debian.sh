#!/usr/bin/env bash
# Idempotent: a Debian package the tests need, installed when what it provides is missing.
# Usage: bash scripts/debian.sh TAG PACKAGE PATH-GLOB WHY
#   TAG: the log's prefix; PATH-GLOB: what the package provides (present: nothing to do)
set -euo pipefail
tag="$1" package="$2" provides="$3" why="$4"
if compgen -G "$provides" > /dev/null; then
  exit 0
fi
if [ "$(id -u)" != 0 ]; then
  echo "[$tag] $provides is missing: run 'sudo apt-get install $package' ($why)" >&2
  exit 1
fi
echo "[$tag] installing Debian's $package"
export DEBIAN_FRONTEND=noninteractive
apt-get update -q >/dev/null
apt-get install -y -q "$package" >/dev/null
echo "[$tag] $(compgen -G "$provides" | head -1)"
