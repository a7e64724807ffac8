#!/usr/bin/env bash
# Refresh the station page's vendored charting library from the npm registry, at the version
# pinned in ros_ehs/web/static/vendor/package.json (the package ships it: no CDN on a rig).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
vendor="$root/ros_ehs/web/static/vendor"
version="$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['dependencies']['uplot'])" "$vendor/package.json")"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
(cd "$tmp" && npm pack --silent "uplot@$version" >/dev/null && tar xzf uplot-*.tgz)
cp "$tmp/package/dist/uPlot.iife.min.js" "$tmp/package/dist/uPlot.min.css" "$vendor/"
cp "$tmp/package/LICENSE" "$vendor/uPlot.LICENSE"
echo "uPlot $version vendored into $vendor"
