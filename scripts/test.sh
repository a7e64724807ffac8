#!/usr/bin/env bash
# Set up (if needed) and run every test, the ament linters included.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
bash "$root/scripts/browser.sh"
bash "$root/scripts/postgres.sh"
source "$root/scripts/env.sh"
cd "$root"
exec python -m pytest "$@"
