#!/usr/bin/env bash
# The PostgreSQL server binaries (initdb, pg_ctl) that the database tests and `make bench`
# start a throwaway cluster with (tools/pg_cluster.py). Installed from Debian where missing
# (as root, or with sudo); nothing is started or enabled here.
set -euo pipefail
if command -v pg_ctl >/dev/null || ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1; then
    exit 0
fi
SUDO=''
[ "$(id -u)" -eq 0 ] || SUDO='sudo'
if ! command -v apt-get >/dev/null; then
    echo 'PostgreSQL server binaries missing and no apt-get: install postgresql (initdb, pg_ctl)' >&2
    exit 1
fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends postgresql-15 \
    || DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends postgresql
# Debian's package starts a cluster of its own on install; the tests do not use it
$SUDO pg_ctlcluster --help >/dev/null 2>&1 && $SUDO service postgresql stop >/dev/null 2>&1 || true
