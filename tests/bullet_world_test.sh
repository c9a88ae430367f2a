#!/usr/bin/env bash
# A short headless Bullet world beside a real daemon on loopback DDS: examples/bullet_world
# pours a few hundred bodies, streams new ones and removes old ones for a few hundred steps, and
# compares the daemon's events with Bullet's pair differences at every step (it exits 1 on any
# difference or missing frame). A recorder takes the update stream meanwhile; the recording then
# replays through `bpctl check` (the daemon's engine against brute force).
# Usage: bullet_world_test.sh BROADPHASED BPCTL BULLET_WORLD SOURCE_DIR DOMAIN
set -euo pipefail
daemon_bin="$1" bpctl_bin="$2" world_bin="$3" src="$4" domain="$5"
work="$(mktemp -d)"
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill -INT "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT
partition="bullet-$$"
cat >"$work/d.yaml" <<YAML
dds:
  domain: $domain
  cyclone_config: $src/config/cyclonedds-loopback.xml
  partition: $partition
logging:
  summary_interval_s: 0
YAML

"$daemon_bin" --config "$work/d.yaml" 2>"$work/daemon.log" &
pids+=($!)
"$bpctl_bin" --config "$work/d.yaml" record "$work/bullet.rec" 2>"$work/record.log" &
pids+=($!)
rc=0
"$world_bin" --bodies 300 --steps 300 --fill-steps 60 --stream 2 --rate 0 --readers 2 \
  --domain "$domain" --partition "$partition" --cyclone-config "$src/config/cyclonedds-loopback.xml" \
  --csv "$work/steps.csv" --json --quiet --wait 60 >"$work/world.out" 2>&1 || rc=$?
cat "$work/world.out"
if ((rc != 0)); then
  echo "bullet_world exited with $rc; daemon log:"
  tail -20 "$work/daemon.log"
  exit 1
fi
grep -q '"checked": 301, "differing": 0, "missing_frames": 0' "$work/world.out" || {
  echo "bullet_world did not compare all 301 frames equal"
  exit 1
}
# The world did something: bodies moved and pairs began and ended at many steps.
awk -F, 'NR > 1 && $5 > 0 { moved++ } NR > 1 && $8 > 0 && $9 > 0 { both++ }
  END { print moved " steps with moved bodies, " both " with collides and uncollides";
        exit !(moved > 200 && both > 50) }' "$work/steps.csv"

# Stop the recorder (it flushes), then check the recording against brute force.
kill -INT "${pids[1]}"
wait "${pids[1]}" || { echo "recorder failed:"; cat "$work/record.log"; exit 1; }
pids=("${pids[0]}")
"$bpctl_bin" --config "$work/d.yaml" check "$work/bullet.rec" | tee "$work/check.out"
grep -q "301 frames" "$work/check.out"
grep -q "identical to brute force" "$work/check.out"
echo "bullet world: events equal Bullet's pairs at every step; the recording checks"
