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
