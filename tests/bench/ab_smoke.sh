#!/usr/bin/env bash
# scripts/ab end to end, small: two runs of one bpbench compare (every timed scene gets a ratio
# line), a build whose rows are not exact is refused, and bad usage is refused with exit 2.
#   tests/bench/ab_smoke.sh BPBENCH AB OUTDIR
set -euo pipefail
bench="$1" ab="$2" out="$3"
rm -rf "$out"
mkdir -p "$out"

"$ab" --rounds 2 --out "$out/rows.jsonl" "$bench" "$bench" -- -e grid_dense -s S2a,S1-10k -r 1 \
  -f 5 >"$out/summary.txt"
cat "$out/summary.txt"
grep -Eq '^S2a grid_dense .*: [0-9.]+ \(rounds ' "$out/summary.txt"
grep -Eq '^S1-10k grid_dense .*: [0-9.]+ \(rounds ' "$out/summary.txt"
rows=$(wc -l <"$out/rows.jsonl")
[[ "$rows" -eq 8 ]] || { echo "ab smoke: expected 8 tagged rows (2 rounds x 2 builds x 2 scenes), got $rows" >&2; exit 1; }
grep -q '"build": "old"' "$out/rows.jsonl" && grep -q '"build": "new"' "$out/rows.jsonl"
# Both builds ran pinned to one CPU, one this process may use (the default, --cpus auto).
allowed=$(python3 -c 'import os; print(" ".join(map(str, sorted(os.sched_getaffinity(0)))))')
pinned=$(sed -n 's/^# cpus: //p' "$out/summary.txt")
[[ " $allowed " == *" $pinned "* ]] ||
  { echo "ab smoke: expected one allowed CPU ($allowed) in '# cpus:', got '$pinned'" >&2; exit 1; }
[[ $(grep -c "\"cpus\": \"$pinned\"" "$out/rows.jsonl") -eq 8 ]] ||
  { echo "ab smoke: every row should be tagged with cpus $pinned" >&2; exit 1; }

# A build that does not reproduce the golden values: refused, with exit 1 and the reason.
fake="$out/not_exact_bench"
printf '#!/bin/sh\necho %s\n' \
  "'{\"scenario\":\"S2a\",\"engine\":\"grid_dense\",\"median_ms\":0.01,\"golden_ok\":false}'" >"$fake"
chmod +x "$fake"
set +e
"$ab" --rounds 1 "$bench" "$fake" -- -e grid_dense -s S2a -r 1 -f 5 >/dev/null 2>"$out/err.txt"
rc=$?
set -e
[[ $rc -eq 1 ]] && grep -q 'does not reproduce the golden values' "$out/err.txt" ||
  { echo "ab smoke: a build that is not exact should be refused (exit $rc)" >&2; cat "$out/err.txt" >&2; exit 1; }

# Bad usage: exit 2, naming the problem.
for args in "$out/missing $bench" "--base-rev no-such-revision-xyz $bench" "--rounds 0 $bench $bench" \
  "--cpus 99999 $bench $bench" "--cpus one $bench $bench"; do
  set +e
  # shellcheck disable=SC2086
  "$ab" $args >/dev/null 2>"$out/err.txt"
  rc=$?
  set -e
  [[ $rc -eq 2 ]] || { echo "ab smoke: '$args' should exit 2, got $rc" >&2; cat "$out/err.txt" >&2; exit 1; }
done
echo "ab smoke: ok"
