#!/usr/bin/env bash
# Idempotent: the browser the station's tests drive, Debian's Chromium (/usr/bin/chromium).
# Playwright (a Python dependency) drives it; nothing is downloaded besides the Debian package.
set -euo pipefail
if [ -x /usr/bin/chromium ]; then
  exit 0
fi
if [ "$(id -u)" != 0 ]; then
  echo "[browser] /usr/bin/chromium is missing: run 'sudo apt-get install chromium' (the" \
       "station's browser tests need it)" >&2
  exit 1
fi
echo "[browser] installing Debian's chromium"
export DEBIAN_FRONTEND=noninteractive
apt-get update -q >/dev/null
apt-get install -y -q chromium >/dev/null
echo "[browser] $(/usr/bin/chromium --version)"
