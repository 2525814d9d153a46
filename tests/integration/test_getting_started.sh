#!/usr/bin/env bash
# A newcomer's first step, as docs/guides/getting-started.md writes it: the commands of its first
# code block ("Train the pendulum") run as written from the source folder (install what is missing,
# build, train), and the run they leave reached the quickstart's result: its stop event says the
# evaluation reached the target, and its summary event counts no batch lost or invalid.
#   tests/integration/test_getting_started.sh SOURCE_DIR
set -uo pipefail
src=$(readlink -f "$1")
guide=$src/docs/guides/getting-started.md
block=$(awk '/^## Train the pendulum/{f=1} f&&/^```/{n++; next} f&&n==1{print} n==2{exit}' "$guide")
[ -n "$block" ] || { echo "FAIL: no code block under 'Train the pendulum' in $guide"; exit 1; }
id=$(sed -n 's/^experiment_id: "\(.*\)"$/\1/p' "$src/deploy/configs/pendulum_sac.txtpb")
run=$src/runs/$id
# A run of the same experiment already there is put aside and given back; what the test makes goes.
saved=""
if [ -e "$run" ]; then
  saved=$(mktemp -d "$src/runs/.$id.saved.XXXXXX")
  mv "$run" "$saved/run"
fi
before=$(ls -d "$src"/runs/"$id"* 2>/dev/null | sort)
cleanup() {
  for d in $(ls -d "$src"/runs/"$id"* 2>/dev/null | sort); do
    grep -qxF "$d" <<<"$before" || rm -rf "$d"
  done
  if [ -n "$saved" ]; then mv "$saved/run" "$run" && rmdir "$saved"; fi
}
trap cleanup EXIT
echo "running, as the guide writes it:"
echo "$block"
(cd "$src" && FARM_DOMAIN=$((100 + RANDOM % 100)) timeout 600 bash -e -c "$block") > /tmp/getting_started.$$.log 2>&1
rc=$?
tail -n 8 /tmp/getting_started.$$.log
rm -f /tmp/getting_started.$$.log
[ "$rc" = 0 ] || { echo "FAIL: the guide's commands exited $rc"; exit 1; }
events=$run/events.jsonl
[ -f "$events" ] || { echo "FAIL: no $events"; exit 1; }
python3 - "$events" <<'PY'
import json, sys
events = [json.loads(l) for l in open(sys.argv[1])]
stop = [e for e in events if e.get("event") == "stop"]
summary = [e for e in events if e.get("event") == "summary"]
ok = True
if not stop or "reached the target" not in stop[-1].get("reason", ""):
    print("FAIL: the run did not stop at its target:", stop[-1] if stop else "no stop event"); ok = False
if not summary or summary[-1].get("batches_lost", 1) != 0 or summary[-1].get("batches_invalid", 1) != 0:
    print("FAIL: the summary counts batches lost or invalid:", summary[-1] if summary else "no summary event"); ok = False
if ok:
    print("PASS: the quickstart stopped at its target (%s), no batch lost or invalid" % stop[-1]["reason"])
sys.exit(0 if ok else 1)
PY
