#!/usr/bin/env bash
# The main job: set up (if needed), then run the bench simulation and report.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
source "$root/scripts/env.sh"
cd "$root"
exec ehs_sim main "$@"
