#!/usr/bin/env bash
# Idempotent: the PostgreSQL server the results store's tests start (Debian's postgresql;
# each test runs one of its own in a temporary directory, as the postgres user: test/postgres.py).
set -euo pipefail
if ls /usr/lib/postgresql/*/bin/postgres > /dev/null 2>&1; then
  exit 0
fi
if [ "$(id -u)" != 0 ]; then
  echo "[postgres] no server under /usr/lib/postgresql: run 'sudo apt-get install" \
       "postgresql' (the results store's tests need it)" >&2
  exit 1
fi
echo "[postgres] installing Debian's postgresql"
export DEBIAN_FRONTEND=noninteractive
apt-get update -q >/dev/null
apt-get install -y -q postgresql >/dev/null
echo "[postgres] $(ls -d /usr/lib/postgresql/*/bin/postgres)"
