#!/usr/bin/env bash
# Training during every attack of docs/record/reliability.md's trust rows, on this machine: per attack
# a fresh pendulum learner (deploy/configs/pendulum_sac.txtpb) and one worker; once the learner has
# updated for WARM seconds, ROUNDS rounds of a quiet window of BEFORE seconds followed by the attack
# (farm_intruder, its own seconds). The learner's updates/s and accepted env steps/s come from its
# learner.csv (one row a second): "before" over all quiet windows together, "during" over all attack
# windows together, so that a rate that drifts or jumps by itself (on a shared 2-core VM it moves
# between about 480 and 780 updates/s with no attack at all) weighs on both sides alike. Then the
# learner and the worker are stopped (SIGINT). Prints one line per attack with both ratios against
# the bound 0.9 (within 10 % of before), the lowest one round gave, and the learner's batch counts at
# the end. The attacks marked "security" run the farm with DDS Security (a PKI from
# deploy/make-pki.sh; the attacker holds a worker certificate of its own, w2: a leaked one).
#   tests/bench/bench_attacks.sh LEARNER WORKER INTRUDER SOURCE_DIR [OUT_DIR]
# Environment: WARM (default 8), BEFORE (default 6), ROUNDS (default 5), DOMAIN (default 150), ONLY
# (the attacks to run, by number, e.g. "3 4"; default all), ATTACKER_NICE (the attacker's nice value).
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
out=${5:-/tmp/farm_bench_attacks}
warm=${WARM:-8} before=${BEFORE:-6} rounds=${ROUNDS:-5} domain=${DOMAIN:-150} only=${ONLY:-} nice=${ATTACKER_NICE:+nice -n $ATTACKER_NICE}
mkdir -p "$out"
# elapsed seconds, updates and env steps at the last row of CSV
last_row() { awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) { if ($i == "updates") u = i; if ($i == "elapsed_s") e = i; if ($i == "env_steps") s = i }; next }
                       { lu = $u; le = $e; ls = $s } END { print le + 0, lu + 0, ls + 0 }' "$1" 2>/dev/null; }
# NAME|SECURITY (0 or 1)|farm_intruder's flags: CFG is the experiment's config, WID the worker's id
attacks=(
  "forged answers|0|--forge-answers -1 --forge-length 200 --seconds 6"
  "specs of another writer|0|--spec-only 1 --spec-config CFG --spec-steps 2147483647 --seconds 6"
  "invented streams and heartbeats|0|--flood-streams 5000 --flood-heartbeats 10000 --status-host-bytes 60000 --seconds 4"
  "200 MiB samples to workers|0|--big-to-workers 200 --seconds 4"
  "malformed samples (bool 2)|0|--malformed bool --seconds 6"
  "length bombs|0|--malformed length --seconds 6"
  "fuzzed samples of every topic|0|--malformed fuzz --fuzz-seed 7 --seconds 6"
  "removals in the learner's name|0|--forge-removal 1 --seconds 6"
  "a copy of the learner's spec|0|--spec-only 1 --spec-config CFG --spec-steps 25 --spec-max-batches 1000 --seconds 6"
  "batches and beats as the worker|0|--id WID --heartbeat 1 --seconds 6"
  "a thief under the worker's session|0|--steal-streams 1 --seconds 6"
  "200 invented live workers|0|--flood-heartbeats 200 --beat-every 1 --seconds 6"
  "forged status to the monitor|0|--heartbeat 1 --status-error disk_failure --seconds 6"
  "wide-spread answers, leaked cert|1|--heartbeat 1 --forge-answers 0 --forge-length 200 --seconds 6"
  "heartbeat flood, leaked cert|1|--flood-heartbeats 2000 --beat-every 0.1 --seconds 6"
  "removals in the learner's name|1|--forge-removal 1 --seconds 6"
  "status as another worker, leaked|1|--id WID --heartbeat 1 --status-error disk_failure --seconds 6"
)
pki="$out/pki"
needs_pki=0
printf '%-44s %9s %9s %6s %9s %9s %6s %6s %6s  %s\n' attack "upd/s" during ratio "steps/s" during ratio bound \
  "lowest" "batches at the end"
k=0
for a in "${attacks[@]}"; do
  name=${a%%|*} rest=${a#*|} k=$((k + 1)) d=$domain
  secure=${rest%%|*} flags=${rest#*|}
  domain=$((domain + 1))
  [ -n "$only" ] && [[ " $only " != *" $k "* ]] && continue
  wid=bw$k
  sec_l=() sec_w=() sec_i=() iid=intruder$k
  if [ "$secure" = 1 ]; then
    if [ "$needs_pki" = 0 ]; then
      rm -rf "$pki"
      workers=()
      for j in $(seq ${#attacks[@]}); do workers+=("worker:bw$j"); done
      bash "$src/deploy/make-pki.sh" "$pki" learner:learner worker:w2 "${workers[@]}" >"$out/pki.log" 2>&1 ||
        { echo "make-pki.sh failed: $(tail -3 "$out/pki.log")"; exit 1; }
      needs_pki=1
    fi
    sec_l=(--security "$pki/learner") sec_w=(--security "$pki/$wid") sec_i=(--security "$pki/w2") iid=w2
  fi
  cfg="$out/a$k.txtpb"
  awk '/^stop \{/ { print "stop { max_seconds: 150 }"; skip = 1; next } skip { if ($0 ~ /^\}/) skip = 0; next } { print }' \
    "$src/deploy/configs/pendulum_sac.txtpb" |
    sed -e "s/^experiment_id: .*/experiment_id: \"bench_attack$k\"/" -e 's/^log_every_seconds: .*/log_every_seconds: 1/' >"$cfg"
  rm -rf "$out/run$k"
  "$learner" --config "$cfg" --run-dir "$out/run$k" --domain $d "${sec_l[@]}" >"$out/learner$k.log" 2>&1 &
  lp=$!
  "$worker" --domain $d --id $wid --envs 4 "${sec_w[@]}" >"$out/worker$k.log" 2>&1 &
  wp=$!
  csv="$out/run$k/learner.csv"
  first=""
  for _ in $(seq 300); do
    read -r e u s < <(last_row "$csv")
    [ -z "$first" ] && [ "${u:-0}" -gt 0 ] && first=$e
    [ -n "$first" ] && awk -v e="$e" -v f="$first" -v w="$warm" 'BEGIN { exit !(e - f >= w) }' && break
    sleep 0.2
  done
  flags=${flags//CFG/$cfg}
  [[ " $flags " == *" --id "* ]] || flags="--id $iid $flags"
  # per round: elapsed, updates and env steps at the quiet window's start, at the attack's start
  # and at its end
  rows=""
  for r in $(seq "$rounds"); do
    read -r e1 u1 s1 < <(last_row "$csv")
    sleep "$before"
    read -r e2 u2 s2 < <(last_row "$csv")
    # shellcheck disable=SC2086
    $nice "$intruder" --domain $d --experiment "bench_attack$k" --obs 3 --act 1 "${sec_i[@]}" ${flags//WID/$wid} \
      >"$out/intruder$k.$r.log" 2>&1
    read -r e3 u3 s3 < <(last_row "$csv")
    rows+="$e1 $u1 $s1 $e2 $u2 $s2 $e3 $u3 $s3"$'\n'
  done
  kill -INT $lp 2>/dev/null
  wait $lp
  kill -INT $wp 2>/dev/null
  wait $wp
  batches=$(awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) c[$i] = i; next }
    { r = "ok " $c["batches_ok"] ", lost " $c["batches_lost"] ", duplicate " $c["batches_duplicate"] ", invalid " $c["batches_invalid"] }
    END { print r }' "$csv")
  [ "$secure" = 1 ] && name="$name (security)"
  awk -v n="$name" -v b="$batches" '
    { tb += $4 - $1; ub += $5 - $2; sb += $6 - $3; td += $7 - $4; ud += $8 - $5; sd += $9 - $6
      if ($4 > $1 && $7 > $4 && $5 > $2) { r = (($8 - $5) / ($7 - $4)) / (($5 - $2) / ($4 - $1)); if (lo == "" || r < lo) lo = r } }
    END {
      ubr = 0; udr = 0; sbr = 0; sdr = 0; ur = 0; sr = 0
      if (tb > 0) { ubr = ub / tb; sbr = sb / tb }
      if (td > 0) { udr = ud / td; sdr = sd / td }
      if (ubr > 0) ur = udr / ubr
      if (sbr > 0) sr = sdr / sbr
      printf "%-44s %9.0f %9.0f %6.2f %9.0f %9.0f %6.2f %6s %6.2f  %s\n", n, ubr, udr, ur, sbr, sdr, sr, "0.9", lo + 0, b }' <<<"$rows"
done
