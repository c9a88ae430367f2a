#!/usr/bin/env bash
# DDS Security end to end: certificates and signed documents from scripts/make-security,
# broadphased and bpctl as separate processes on loopback, domain $1.
#   - an authorised producer's scene reaches the daemon and an authorised watcher gets its events,
#     and those of its interest (in a sub-partition);
#   - an intruder with a complete setup of its own (its own CAs and a permissions document that
#     grants it everything) and a participant without security can neither publish updates (no
#     daemon ever matches their writers) nor read events (their watchers get none);
#   - an authenticated participant whose permissions cover only the status topic cannot create
#     an events reader (Not Allowed By Security) but may read the daemon's status;
#   - the producer's grant covers partition world1 only: in world2 it cannot create its writer.
# Usage: security_test.sh DOMAIN BROADPHASED BPCTL SOURCE_DIR
set -uo pipefail
DOMAIN="$1" BROADPHASED="$(realpath "$2")" BPCTL="$(realpath "$3")" SRC="$(realpath "$4")"
DIR="$(mktemp -d /tmp/bp-security.XXXXXX)"
DAEMON_PID=""
cleanup() {
  [[ -n "$DAEMON_PID" ]] && kill -9 "$DAEMON_PID" 2>/dev/null
  rm -rf "$DIR"
}
trap cleanup EXIT
failures=0
check() {  # check DESCRIPTION COMMAND...
  if "${@:2}"; then echo "ok: $1"; else echo "FAILED: $1"; failures=$((failures + 1)); fi
}

"$SRC/scripts/make-security" "$DIR" --domain "$DOMAIN" --partition world1 >/dev/null || exit 1
cd "$DIR"
printf 'logging:\n  summary_interval_s: 0.5\n' >>daemon.yaml  # status reports twice a second
"$BROADPHASED" -c daemon.yaml >daemon.log 2>&1 &
DAEMON_PID=$!

# Watchers first (they wait for the daemon), then the publishers.
"$BPCTL" -c watcher.yaml --wait 10 watch --seconds 16 >watcher.out 2>watcher.err &
W1=$!
"$BPCTL" -c intruder.yaml --wait 10 watch --seconds 12 >intruder_watch.out 2>intruder_watch.err &
W2=$!
# An interest: its events come in a sub-partition of world1, which the grants cover.
"$BPCTL" -c watcher.yaml --wait 10 watch --seconds 16 --region -1e6,-1e6,-1e6,1e6,1e6,1e6 \
  >interest_watch.out 2>interest_watch.err &
W4=$!
"$BPCTL" -c plain.yaml --wait 10 watch --seconds 12 >plain_watch.out 2>plain_watch.err &
W3=$!
sleep 2
"$BPCTL" -c intruder.yaml --wait 4 scene -n 100 --producer 9 --frames 30 --rate 30 -q >intruder_scene.log 2>&1
intruder_rc=$?
"$BPCTL" -c plain.yaml --wait 4 scene -n 100 --producer 10 --frames 30 --rate 30 -q >plain_scene.log 2>&1
plain_rc=$?
"$BPCTL" -c producer.yaml --wait 10 scene -n 200 --producer 1 --frames 60 --rate 30 -q >producer.log 2>&1
producer_rc=$?
sed 's/partition: world1/partition: world2/' producer.yaml >producer_world2.yaml
"$BPCTL" -c producer_world2.yaml --wait 4 scene -n 10 --producer 2 --frames 5 -q >world2.log 2>&1
world2_rc=$?
"$BPCTL" -c auditor.yaml --wait 5 watch --seconds 2 >auditor_watch.out 2>&1
auditor_watch_rc=$?
sleep 1  # a periodic report after the scene's last frame
"$BPCTL" -c auditor.yaml --wait 5 status --timeout 5 >auditor_status.out 2>&1
auditor_status_rc=$?
wait "$W1" "$W2" "$W3" "$W4"

events() { grep -cE '^[0-9]+ (collide|uncollide) ' "$1" || true; }
check "the authorised producer published (exit 0)" test "$producer_rc" -eq 0
check "the authorised watcher got events ($(events watcher.out))" test "$(events watcher.out)" -gt 0
# Keys print as producer:id. (A pattern over whole lines once matched a log line's time of day,
# 10:04, when Cyclone's warnings still went to bpctl's stdout.)
others() { grep -E '^[0-9]+ (collide|uncollide) ' "$1" | grep -cvE '^[0-9]+ [a-z]+ 1:[0-9]+ 1:[0-9]+$' || true; }
check "every event it got is producer 1's" test "$(others watcher.out)" -eq 0
check "  and its standard output holds events only" \
  test "$(grep -cvE '^[0-9]+ (collide|uncollide) [0-9]+:[0-9]+ [0-9]+:[0-9]+$' watcher.out)" -eq 0
check "the authorised watcher's interest got its region's events" \
  test "$(grep -cE '^[0-9]+ collide region:0 1:[0-9]+$' interest_watch.out || true)" -gt 0
check "the intruder's scene found no daemon (exit $intruder_rc)" test "$intruder_rc" -eq 1
check "  and says so" grep -q "no daemon" intruder_scene.log
check "the unauthenticated scene found no daemon (exit $plain_rc)" test "$plain_rc" -eq 1
check "the intruder's watcher got no events" test "$(events intruder_watch.out)" -eq 0
check "  and printed nothing on stdout (its handshake warnings go to stderr)" \
  test ! -s intruder_watch.out
check "the unauthenticated watcher got no events" test "$(events plain_watch.out)" -eq 0
check "the producer may not publish in another partition (exit $world2_rc)" test "$world2_rc" -eq 1
check "  Not Allowed By Security" grep -q "Not Allowed By Security" world2.log
check "the auditor may not read events (exit $auditor_watch_rc)" test "$auditor_watch_rc" -eq 1
check "  Not Allowed By Security" grep -q "Not Allowed By Security" auditor_watch.out
check "the auditor reads the status (exit $auditor_status_rc)" test "$auditor_status_rc" -eq 0
check "  which counts producer 1's 200 objects and one producer" \
  grep -qE "objects 200, overlaps [0-9]+, producers 1 " auditor_status.out
kill -TERM "$DAEMON_PID"
wait "$DAEMON_PID"
daemon_rc=$?
DAEMON_PID=""
check "the daemon exits 0" test "$daemon_rc" -eq 0
check "  and rejected nothing" grep -q "0 rejected items" daemon.log
if ((failures > 0)); then
  echo "----- watcher.out: lines other than producer 1's events"
  grep -vE '^[0-9]+ [a-z]+ 1:[0-9]+ 1:[0-9]+$' watcher.out | head -n 15
  for f in daemon.log watcher.err interest_watch.err intruder_watch.out intruder_watch.err plain_watch.err intruder_scene.log \
           plain_scene.log producer.log world2.log auditor_watch.out auditor_status.out; do
    echo "----- $f"; tail -n 15 "$f"
  done
  exit 1
fi
echo "DDS Security: all checks passed"
