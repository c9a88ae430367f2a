#!/usr/bin/env bash
# bpbench and scripts/plot end to end, small: the peer libraries compiled into this build must
# reproduce WORKLOADS.md's golden S2a values and our engine's overlap sets; the hard scenes, the
# float-vs-double error, Figure 2, the error sweep and labelled runs must run and give
# well-formed lines; and scripts/plot must draw every figure kind and table from them.
#   tests/bench/smoke.sh BPBENCH PLOT OUTDIR
set -euo pipefail
bench="$1" plot="$2" out="$3"
rm -rf "$out"
mkdir -p "$out"
json="$out/smoke.jsonl"

# Every peer whose Debian package is installed must be in this build (scripts/setup installs all).
peers="$("$bench" --peers list)"
for pair in libbullet-dev:bullet_dbvt libbullet-dev:bullet_sap libfcl-dev:fcl_dynamic_tree \
  libcgal-dev:cgal; do
  pkg="${pair%%:*}" peer="${pair#*:}"
  if [[ "$(dpkg-query -W -f='${db:Status-Status}' "$pkg" 2>/dev/null || true)" == installed ]] &&
    ! grep -q "^$peer " <<<"$peers"; then
    echo "bench smoke: $pkg is installed but bpbench has no $peer peer" >&2
    exit 1
  fi
done
if [[ "$peers" != *"no peer"* ]] && "$bench" -s S2a -r 1 -f 2 --peers all --world-box >/dev/null 2>&1; then
  echo "bench smoke: --peers with --world-box should be refused" >&2
  exit 1
fi

"$bench" -s S2a -e grid_dense -r 1 --peers all >"$json"
"$bench" -s S1-10k -e grid_dense -r 1 -f 10 --shape clustered >>"$json"
"$bench" -s S1-10k -e grid_segmented_sap -r 1 -f 10 --coord double --offset 1e12 >>"$json"
"$bench" -s S1-10k -e grid_dense -r 1 -f 10 --error-vs-double --offset 1e5 >>"$json"
"$bench" -s S2a -e grid_dense -r 1 -f 10 --margin-sweep 0.1 0.3 >>"$json"
"$bench" --figure 2 -r 1 -f 3 --sweep-sizes 500 1000 2000 >>"$json"
# The declarations table (scripts/results declare): labelled runs, the first label the reference.
for round in 1 2; do
  "$bench" -s S2a -e grid_dense -r 1 -f 4 --label "all dynamic" >>"$json"
  "$bench" -s S2a -e grid_dense -r 1 -f 4 --unpaired-every 2 --label "half unpaired" >>"$json"
done
if "$bench" -s S2a -e grid_dense -r 1 -f 2 --label 'a"b' >/dev/null 2>&1; then
  echo "bench smoke: a label with a quote should be refused" >&2
  exit 1
fi

/usr/bin/python3 - "$json" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
def fail(msg):
    sys.exit("bench smoke: " + msg)
s2a = [d for d in rows if d.get("scenario") == "S2a" and "margin" not in d]
if not s2a or s2a[0].get("golden_ok") is not True:
    fail("grid_dense S2a does not reproduce the golden values")
peers = [d for d in s2a if "library" in d]
print(f"bench smoke: {len(peers)} peer libraries ran")
for d in peers:
    if d.get("golden_ok") is not True or d.get("same_set_as_engine") is not True:
        fail(f"peer {d['engine']} does not reproduce S2a exactly: {d}")
    if not d.get("ratio_to_engine", 0) > 0:
        fail(f"peer {d['engine']} has no ratio")
clustered = [d for d in rows if d.get("shape") == "clustered"]
if not clustered or clustered[0]["errors"] != 0 or clustered[0]["pairs"] < 10000:
    fail("clustered scene missing, refused or not crowded")
far = [d for d in rows if d.get("offset") == 1e12]
if not far or far[0]["cell_size"] > 100:
    fail("a world at 1e12 should keep small cells: " + str(far[:1]))
err = [d for d in rows if d.get("error_vs") == "double"]
if not err or err[0]["false_neg_per_frame"] != 0 or err[0]["false_pos_per_frame"] <= 0:
    fail("float fed double input at 1e5: expected false positives and no false negatives")
margins = [d for d in rows if d.get("margin")]
if len(margins) != 2 or any(d["false_neg_per_frame"] != 0 for d in margins):
    fail("fat boxes must never miss a pair")
fits = [d for d in rows if d.get("scenario") == "fig2-fit"]
if len(fits) != 4 or not all(0.5 < d["work_exponent"] < 3 for d in fits):
    fail("figure 2 fits missing or absurd: " + str(fits))
PY

"$plot" --out "$out" "$json" >"$out/plot.out"
for f in fig2 error hard; do
  test -s "$out/$f.png" || { echo "bench smoke: scripts/plot drew no $f.png" >&2; exit 1; }
done
if ! grep -q "^### What each declaration saves (S2a, grid_dense, 4 frames, 2 rounds)" \
  "$out/tables.md" || ! grep -q "^| half unpaired | " "$out/tables.md"; then
  echo "bench smoke: scripts/plot wrote no declarations table" >&2
  exit 1
fi
if grep -q '"library"' "$json"; then
  test -s "$out/peers.png" || { echo "bench smoke: scripts/plot drew no peers.png" >&2; exit 1; }
fi
echo "bench smoke: ok"
