#!/usr/bin/env bash
# The shipped mCLARI policy (docs/data/mclari_terrain_policy, seed 1 of
# deploy/configs/mclari_sac_terrain.txtpb at 70,864 env steps, docs/record/mclari.md step 11) still meets
# the goal on every terrain: >= 90 % of the 180 s sweep's best fixed point and no fall, over one
# episode per terrain (10 in the docs): 180 s of simulation each, the most expensive of the suite. Fails when the model, the task or the policy loading
# changes what the policy does. The folder's policy file (read by farm-mclari-eval without LibTorch)
# is the one farm-policy-file --config writes from the folder's networks, and a folder of networks
# without it is refused with the command that writes it.
# usage: test_mclari_policy.sh EVAL SOURCE_DIR POLICY_FILE_PROGRAM
set -euo pipefail
EVAL=$1 SRC=$2 POLICY_FILE=$3
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
cfg=$SRC/deploy/configs/mclari_sac_terrain.txtpb
# A checkpoint whose manifest's task (9 observations) is not the --config's (mclari_sac.txtpb, 6):
# the threads that evaluate the terrains meet the mismatch, and the program says so and exits 2
# (not an abort from a thread's uncaught error).
mkdir "$T/manifest" && cp -r "$SRC/docs/data/mclari_terrain_policy/." "$T/manifest/"
python3 -c 'import json, sys; print("experiment_id: \"m\"\npolicy_version: 5\nupdates: 100\nconfig_text: "
                + json.dumps(open(sys.argv[1]).read(), ensure_ascii=False))' "$cfg" > "$T/manifest/manifest.txtpb"
rc=0; "$EVAL" --config "$SRC/deploy/configs/mclari_sac.txtpb" --checkpoint "$T/manifest" --episodes 1 --threads 2 \
  --out "$T/mismatch.md" > /dev/null 2> "$T/mismatch.err" || rc=$?
[ $rc = 2 ] && [ ! -e "$T/mismatch.md" ] && grep -q "do not fit task 'mclari'" "$T/mismatch.err" ||
  fail "another task's config: exit $rc, $(cat "$T/mismatch.err")"
# A --best file that would misread the reference is refused before any episode, naming what is wrong.
best_csv=$SRC/docs/data/mclari_best_180s.csv
cut -d, -f1-5,7- "$best_csv" > "$T/no_efficiency.csv"                 # no efficiency column
sed '2s/,0.262360,/,0.262360abc,/' "$best_csv" > "$T/junk.csv"          # a number with junk after it
sed '3s/^1,/0,/' "$best_csv" > "$T/twice.csv"                         # terrain 0 twice
for bad in "no_efficiency.csv|the header has no column 'efficiency'" "junk.csv|efficiency '0.262360abc' is not a finite number" \
           "twice.csv|terrain 0 appears a second time"; do
  rc=0; "$EVAL" --config "$cfg" --checkpoint "$SRC/docs/data/mclari_terrain_policy" --best "$T/${bad%%|*}" --episodes 1 \
    --out "$T/refused.md" > /dev/null 2> "$T/best.err" || rc=$?
  [ $rc = 2 ] && [ ! -e "$T/refused.md" ] && grep -qF "${bad#*|}" "$T/best.err" ||
    fail "--best ${bad%%|*}: exit $rc, $(cat "$T/best.err")"
done
mkdir "$T/networks" && cp -r "$SRC/docs/data/mclari_terrain_policy/sac" "$T/networks/"
if "$EVAL" --config "$cfg" --checkpoint "$T/networks" --episodes 1 > "$T/no_file.out" 2> "$T/no_file.err"; then
  fail "a folder without a policy file was evaluated"
fi
grep -q "farm-policy-file --config $cfg $T/networks" "$T/no_file.err" || fail "no command named: $(cat "$T/no_file.err")"
"$POLICY_FILE" --config "$cfg" "$T/networks" > "$T/policy_file.out" || fail "farm-policy-file --config failed"
cmp "$T/networks/policy.bin" "$SRC/docs/data/mclari_terrain_policy/policy.bin" ||
  fail "the shipped policy.bin is not the policy of the shipped networks"
"$EVAL" --config "$SRC/deploy/configs/mclari_sac_terrain.txtpb" --checkpoint "$SRC/docs/data/mclari_terrain_policy" \
    --best "$SRC/docs/data/mclari_best_180s.csv" --episodes 1 --threads 2 --out "$T/table.md" \
    > "$T/eval.out" 2> "$T/eval.err" || { cat "$T/eval.err"; fail "evaluation failed"; }
cat "$T/table.md"
grep -q "not like for like\|does not say how long" "$T/table.md" && fail "the comparison is not like for like"
python3 - "$T/table.md" <<'PY'
import sys
rows = [[c.strip() for c in l.split("|")[1:-1]] for l in open(sys.argv[1]) if l.startswith("| ")]
rows = [r for r in rows if r[0].startswith(("plain-", "rough-"))]
names = [r[0] for r in rows]
assert names == ["plain-normal", "plain-wet", "plain-dry", "rough-normal", "rough-wet", "rough-dry"], names
for r in rows:
    terrain, episodes, falls, ratio = r[0], r[1], r[3], r[-1]
    assert episodes == "1", r
    assert falls == "0 / 1", "%s: falls %s" % (terrain, falls)
    pct = int(ratio.rstrip(" %"))
    assert pct >= 90, "%s: %d %% of the best fixed point" % (terrain, pct)
    print("%s: %d %%, falls %s" % (terrain, pct, falls))
PY
echo "PASS"
