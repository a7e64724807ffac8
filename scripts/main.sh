#!/usr/bin/env bash
# The main job: set up (if needed), record a bench run to a bag, then identify on that bag.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$root/scripts/setup.sh"
source "$root/scripts/env.sh"
cd "$root"
rm -rf out/bench_run
ehs_sim record --out out/bench_run --duration 10
exec ehs_sim identify out/bench_run --out out/identification "$@"
