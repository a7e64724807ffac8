#!/usr/bin/env bash
# Idempotent set-up: a virtual environment in .venv with every pinned dependency and ros_ehs
# installed (editable), so its console scripts are on the venv's PATH. Safe to re-run.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${EHS_VENV:-$root/.venv}"
py="${PYTHON:-python3}"
stamp="$venv/.ros_ehs_setup"
want="$(cat "$root/requirements.txt" "$root/constraints.txt" "$root/setup.py" "$root/scripts/setup.sh" | sha256sum | cut -c1-16)"
if ! { [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; }; then
  echo "[setup] creating $venv"
  "$py" -m venv "$venv"
  "$venv/bin/python" -m pip install -q --upgrade 'pip==25.3' 'setuptools==79.0.1' \
    'wheel==0.45.1' 'uv==0.13.9'
  # uv installs the same pinned wheels as pip would, fetched and unpacked in parallel (a
  # third of pip's time). It byte-compiles nothing, and where PYTHONDONTWRITEBYTECODE is set
  # no import writes a .pyc either: every process would compile its modules again (the suite
  # took 10 min instead of 7.5 so), hence compileall, on every core
  "$venv/bin/uv" pip install -q --python "$venv/bin/python" -r "$root/requirements.txt" \
    -c "$root/constraints.txt"
  "$venv/bin/python" -m compileall -q -j 0 "$venv/lib" > /dev/null
  "$venv/bin/python" -m pip install -q --no-deps --no-build-isolation -e "$root"
  echo "$want" > "$stamp"
  echo "[setup] done"
fi
# this package's own modules are compiled too (compileall rewrites only what changed): each
# node process would otherwise compile them at its start
"$venv/bin/python" -m compileall -q -j 0 "$root/ros_ehs" "$root/ros_ehs_msgs_py" \
  "$root/launch_scripts" > /dev/null
# numba compiles the model's kernels at their first call and caches them where env.sh says:
# compile them here, once, so the first node does not (a fresh cache takes ~10 s; a warm one
# loads in under a second; a change to the kernels' sources or options compiles them into a
# new directory: kernels.CACHE_DIR)
(source "$root/scripts/env.sh" &&
  python -c 'from ros_ehs.core.model.plant import compile_kernels; compile_kernels()')
