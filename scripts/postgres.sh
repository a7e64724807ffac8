#!/usr/bin/env bash
# Idempotent: the PostgreSQL server the results store's tests start (Debian's postgresql;
# each test runs one of its own in a temporary directory, as the postgres user: test/postgres.py).
set -euo pipefail
exec bash "$(dirname "${BASH_SOURCE[0]}")/debian.sh" postgres postgresql \
  '/usr/lib/postgresql/*/bin/postgres' "the results store's tests need it"
