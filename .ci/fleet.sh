#!/usr/bin/env bash
# The PostgreSQL server of the fleet store tests and benchmark: installs Debian's postgresql when
# it is missing, starts a private cluster on 127.0.0.1 (not the system one), and writes the admin
# DSN to $CELLGUARD_FLEET_DSN_FILE, which the tests read. Idempotent: a running cluster is kept.
#   usage: .ci/fleet.sh            (start)      .ci/fleet.sh stop
set -euo pipefail
PGROOT=${CELLGUARD_FLEET_PGDIR:-/tmp/cellguard-fleet-pg}
PORT=${CELLGUARD_FLEET_PGPORT:-55432}
DSN_FILE=${CELLGUARD_FLEET_DSN_FILE:-/tmp/cellguard-fleet-dsn}

if ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >/dev/null
fi
BIN=$(ls -d /usr/lib/postgresql/*/bin | sort -V | tail -1)
as_pg() { if [ "$(id -u)" = 0 ]; then runuser -u postgres -- "$@"; else "$@"; fi; }

if [ "${1:-start}" = stop ]; then
  as_pg "$BIN/pg_ctl" -D "$PGROOT/data" -m fast stop || true
  exit 0
fi

mkdir -p "$PGROOT"
[ "$(id -u)" = 0 ] && chown postgres "$PGROOT"
if [ ! -f "$PGROOT/data/PG_VERSION" ]; then
  as_pg "$BIN/initdb" -D "$PGROOT/data" -U postgres -A scram-sha-256 --auth-local=peer >/dev/null
  # the admin over the cluster's own socket (OS user postgres or root mapped to it); tenants by password on loopback
  as_pg bash -c "cat > '$PGROOT/data/pg_ident.conf'" <<EOF
admin root postgres
admin postgres postgres
EOF
  as_pg bash -c "cat > '$PGROOT/data/pg_hba.conf'" <<EOF
local all postgres peer map=admin
host  all all 127.0.0.1/32 scram-sha-256
EOF
fi
if ! as_pg "$BIN/pg_ctl" -D "$PGROOT/data" status >/dev/null 2>&1; then
  as_pg "$BIN/pg_ctl" -D "$PGROOT/data" -l "$PGROOT/server.log" -w \
    -o "-p $PORT -k $PGROOT -c listen_addresses=127.0.0.1 -c fsync=off" start >/dev/null
fi
echo "host=$PGROOT port=$PORT user=postgres dbname=postgres" > "$DSN_FILE"
echo "fleet store server: $(cat "$DSN_FILE") (DSN in $DSN_FILE)"
