#!/bin/bash
# The official postgres image's first-start contract (see postgres.Dockerfile), then the server.
set -euo pipefail
if [ "${1:0:1}" = "-" ]; then
    set -- postgres "$@"
fi
if [ "$1" != "postgres" ]; then
    exec "$@"
fi
if [ "$(id -u)" = 0 ]; then  # fix the volume's owner, then run this script again as postgres
    mkdir -p "$PGDATA"
    chown postgres:postgres "$PGDATA"
    chmod 700 "$PGDATA"
    exec setpriv --reuid=postgres --regid=postgres --init-groups "$0" "$@"
fi

POSTGRES_USER=${POSTGRES_USER:-postgres}
POSTGRES_DB=${POSTGRES_DB:-$POSTGRES_USER}
AUTH=${POSTGRES_HOST_AUTH_METHOD:-scram-sha-256}
if [ ! -s "$PGDATA/PG_VERSION" ]; then
    if [ -z "${POSTGRES_PASSWORD:-}" ] && [ "$AUTH" != trust ]; then
        echo "postgres: POSTGRES_PASSWORD is not set (or set POSTGRES_HOST_AUTH_METHOD=trust)" >&2
        exit 1
    fi
    pw=()
    if [ -n "${POSTGRES_PASSWORD:-}" ]; then  # a file only initdb reads, gone right after
        pwfile=$(mktemp)
        printf '%s\n' "$POSTGRES_PASSWORD" > "$pwfile"
        pw=(--pwfile="$pwfile")
    fi
    # shellcheck disable=SC2086 # POSTGRES_INITDB_ARGS is a list of options, as officially
    initdb --username="$POSTGRES_USER" "${pw[@]}" --auth-local=trust --auth-host="$AUTH" \
        ${POSTGRES_INITDB_ARGS:-} >/dev/null
    rm -f "${pwfile:-}"
    printf '\nhost all all all %s\n' "$AUTH" >> "$PGDATA/pg_hba.conf"
    # set up on a private socket only, so that no client (nor the health check) sees the
    # server before the database exists
    init_sock=$(mktemp -d)
    pg_ctl -D "$PGDATA" -o "-c listen_addresses='' -c unix_socket_directories=$init_sock" \
        -w start >/dev/null
    if [ "$POSTGRES_DB" != postgres ]; then
        psql -v ON_ERROR_STOP=1 -h "$init_sock" --username "$POSTGRES_USER" --dbname postgres -q \
            -c "CREATE DATABASE \"$POSTGRES_DB\"" >/dev/null
    fi
    pg_ctl -D "$PGDATA" -m fast -w stop >/dev/null
    echo "postgres: initialised $PGDATA (user $POSTGRES_USER, database $POSTGRES_DB)"
fi
shift
exec postgres -c listen_addresses='*' "$@"
