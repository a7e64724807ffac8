#!/usr/bin/env bash
# Idempotent: the browser the station's tests drive, Debian's Chromium (/usr/bin/chromium).
# Playwright (a Python dependency) drives it; nothing is downloaded besides the Debian package.
set -euo pipefail
exec bash "$(dirname "${BASH_SOURCE[0]}")/debian.sh" browser chromium /usr/bin/chromium \
  "the station's browser tests need it"
