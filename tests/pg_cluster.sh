#!/bin/sh
# pg_cluster.sh - a throw-away PostgreSQL + PostGIS cluster for the tests (tests/pg_fixture.c).
#   pg_cluster.sh start DIR WATCH_PID   initdb in DIR (created; run as nobody when root, since
#                                       PostgreSQL refuses root), start it on 127.0.0.1 only on a
#                                       free port, print the port; the cluster stops and DIR is
#                                       removed when process WATCH_PID (the test runner) ends
#   pg_cluster.sh stop DIR              stop it now and remove DIR
# PG_FSYNC=on (default off: a test cluster need not survive a crash) for benchmarks.
# Exit status 77 (and one line saying what is missing) when the Debian packages postgresql and
# postgresql-15-postgis-3 are not installed.
set -eu
cmd=$1 dir=$2
bin=$(pg_config --bindir 2>/dev/null || echo /usr/lib/postgresql/15/bin)
share=$(pg_config --sharedir 2>/dev/null || echo /usr/share/postgresql/15)
as=""
[ "$(id -u)" -eq 0 ] && as="runuser -u nobody --"
case $cmd in
stop)
    [ -f "$dir/data/postmaster.pid" ] && $as "$bin/pg_ctl" -D "$dir/data" -m fast -w stop >/dev/null 2>&1 || true
    rm -rf "$dir" "$dir.lock"
    exit 0 ;;
start) ;;
*) echo "usage: pg_cluster.sh start DIR WATCH_PID | stop DIR" >&2; exit 2 ;;
esac
watch=$3
if [ ! -x "$bin/initdb" ] || [ ! -x "$bin/postgres" ]; then
    echo "no PostgreSQL server ($bin/initdb): install the Debian package postgresql (make deps)"
    exit 77
fi
if [ ! -f "$share/extension/postgis.control" ]; then
    echo "no PostGIS ($share/extension/postgis.control): install postgresql-15-postgis-3 (make deps)"
    exit 77
fi
rm -rf "$dir"
mkdir -m 0755 "$dir"
[ -n "$as" ] && chown nobody "$dir"
$as "$bin/initdb" -D "$dir/data" -U gs -A trust -E UTF8 --locale=C --no-sync >"$dir/initdb.log" 2>&1 ||
    { echo "initdb failed:"; cat "$dir/initdb.log"; exit 1; }
port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
# its own session: the runner's kill of a test's process group does not reach the server
setsid -w $as "$bin/pg_ctl" -D "$dir/data" -l "$dir/server.log" -w -t 60 \
    -o "-c listen_addresses=127.0.0.1 -p $port -c unix_socket_directories=$dir -c fsync=${PG_FSYNC:-off} -c shared_buffers=64MB -c max_connections=40" \
    start >/dev/null || { echo "the server did not start:"; cat "$dir/server.log"; exit 1; }
echo "$port" >"$dir/port"
# the watchdog: stop the cluster and remove it once the runner has gone
setsid sh -c "while kill -0 $watch 2>/dev/null; do sleep 1; done; $0 stop '$dir'" </dev/null >/dev/null 2>&1 &
echo "$port"
