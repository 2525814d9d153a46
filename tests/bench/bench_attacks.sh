#!/usr/bin/env bash
# The learner's updates/s before and during each attack of docs/record/reliability.md's trust rows, on
# this machine: per attack a fresh pendulum learner (deploy/configs/pendulum_sac.txtpb) and one
# worker; once the learner has updated for WARM seconds, the updates/s of the BEFORE seconds just
# passed, then the attack (farm_intruder), then the updates/s of the attack's seconds, from the
# learner's learner.csv (one row a second). Prints one line per attack with the ratio against the
# bound 0.9 (within 10 % of before), and the learner's batch counts at the end.
#   tests/bench/bench_attacks.sh LEARNER WORKER INTRUDER SOURCE_DIR [OUT_DIR]
# Environment: WARM (default 8), BEFORE (default 5), DOMAIN (default 150), ONLY (the attacks to run,
# by number, e.g. "3 4"; default all).
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
out=${5:-/tmp/farm_bench_attacks}
warm=${WARM:-8} before=${BEFORE:-5} domain=${DOMAIN:-150} only=${ONLY:-}
mkdir -p "$out"
# updates at the last row of CSV, and its elapsed seconds
last_row() { awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) { if ($i == "updates") u = i; if ($i == "elapsed_s") e = i }; next }
                       { lu = $u; le = $e } END { print le + 0, lu + 0 }' "$1" 2>/dev/null; }
attacks=(
  "forged answers|--forge-answers -1 --forge-length 200 --seconds 6"
  "specs of another writer|--spec-only 1 --spec-config CFG --spec-steps 2147483647 --seconds 6"
  "invented streams and heartbeats|--flood-streams 5000 --flood-heartbeats 10000 --status-host-bytes 60000 --seconds 4"
  "200 MiB samples to workers|--big-to-workers 200 --seconds 4"
)
printf '%-34s %12s %12s %7s %6s  %s\n' attack "before upd/s" "during upd/s" ratio bound "batches at the end"
k=0
for a in "${attacks[@]}"; do
  name=${a%%|*} flags=${a#*|} k=$((k + 1)) d=$domain
  domain=$((domain + 1))
  [ -n "$only" ] && [[ " $only " != *" $k "* ]] && continue
  cfg="$out/a$k.txtpb"
  awk '/^stop \{/ { print "stop { max_seconds: 40 }"; skip = 1; next } skip { if ($0 ~ /^\}/) skip = 0; next } { print }' \
    "$src/deploy/configs/pendulum_sac.txtpb" |
    sed -e "s/^experiment_id: .*/experiment_id: \"bench_attack$k\"/" -e 's/^log_every_seconds: .*/log_every_seconds: 1/' >"$cfg"
  rm -rf "$out/run$k"
  "$learner" --config "$cfg" --run-dir "$out/run$k" --domain $d >"$out/learner$k.log" 2>&1 &
  lp=$!
  "$worker" --domain $d --id bw$k --envs 4 >"$out/worker$k.log" 2>&1 &
  wp=$!
  csv="$out/run$k/learner.csv"
  first=""
  for _ in $(seq 300); do
    read -r e u < <(last_row "$csv")
    [ -z "$first" ] && [ "${u:-0}" -gt 0 ] && first=$e
    [ -n "$first" ] && awk -v e="$e" -v f="$first" -v w="$warm" 'BEGIN { exit !(e - f >= w) }' && break
    sleep 0.2
  done
  read -r e1 u1 < <(last_row "$csv")
  sleep "$before"
  read -r e2 u2 < <(last_row "$csv")
  # shellcheck disable=SC2086
  "$intruder" --domain $d --experiment "bench_attack$k" --id intruder$k --obs 3 --act 1 ${flags//CFG/$cfg} \
    >"$out/intruder$k.log" 2>&1
  read -r e3 u3 < <(last_row "$csv")
  wait $lp
  wait $wp
  batches=$(grep '^batches' "$out/run$k/summary.txt" 2>/dev/null | sed 's/^batches *//')
  awk -v n="$name" -v e1="$e1" -v u1="$u1" -v e2="$e2" -v u2="$u2" -v e3="$e3" -v u3="$u3" -v b="$batches" 'BEGIN {
    rb = 0; rd = 0; r = 0
    if (e2 > e1) rb = (u2 - u1) / (e2 - e1)
    if (e3 > e2) rd = (u3 - u2) / (e3 - e2)
    if (rb > 0) r = rd / rb
    printf "%-34s %12.0f %12.0f %7.2f %6s  %s\n", n, rb, rd, r, "0.9", b }'
done
