#!/usr/bin/env bash
# Time to goal over seeds and worker counts: for each seed, CONFIG with its `seed:` line set and its
# top-level `stop { }` replaced, one tests/bench/bench_workers.sh run per count (in the order given),
# then one table: per seed the time to goal, updates/s and update-to-data of each count, and each
# later count's time over the first count's, with how many seeds are within a bound of it.
#   tests/bench/bench_seeds.sh LEARNER_BIN WORKER_BIN CONFIG "1 2 3 4 5" "2 15" [OUT_DIR]
# Environment (and bench_workers.sh's: PARALLEL, CPUS_PER_RUN, GPUS, DOMAIN):
#   STOP='...'        the stop { } body (default: eval_goal { metric: "success" at_least: 0.95 }
#                     max_seconds: 150)
#   SET_BLOCK=sac     a top-level block of CONFIG that SET_LINES go into (e.g. "sac", "eval")
#   SET_LINES='...'   lines added at the start of that block, e.g. 'n_step: 3'; a field the block
#                     already sets is replaced (its line dropped), e.g. SET_BLOCK=eval
#                     SET_LINES='episodes: 60' for runs whose evaluations must cost less
#   RATIO_AT_MOST=0.5 the bound the ratios are counted against
#   REPORT_ONLY=1     no runs: the table from the runs already in OUT_DIR
#   CONFIG_ONLY=1     no runs: only write each seed's config, OUT_DIR/seedN.txtpb
#   GOAL_RETURN=12000 also report, from each run's events.jsonl, when its evaluations first reached
#                     that return and whether it kept it (tests/bench/keep_report.py; KEEP_WITHIN,
#                     default 0.1, is the fraction of the kept best a later evaluation may lose)
# A run that ends on a limit, not at the goal, shows "-" and counts as not within the bound. Below
# the table: each count's median time to goal (and the median ratio) over the seeds that reached
# it, a sign test of the ratios against the bound, then each run's evaluations from its learner's
# events (the goal's metric at the time asked), then per count the updates made when the goal's
# evaluation was asked.
set -euo pipefail
if [ $# -lt 5 ]; then
  sed -n '2,21p' "$0" >&2
  exit 2
fi
learner=$1 worker=$2 config=$3 seeds=$4 counts=$5
out=${6:-/tmp/farm_bench_seeds}
stop=${STOP:-'eval_goal { metric: "success" at_least: 0.95 } max_seconds: 150'}
block=${SET_BLOCK:-} lines=${SET_LINES:-} bound=${RATIO_AT_MOST:-0.5}
here=$(cd "$(dirname "$0")" && pwd)
[ -r "$config" ] || { echo "bench_seeds: cannot read config $config" >&2; exit 2; }
grep -q '^seed:' "$config" || { echo "bench_seeds: $config has no top-level 'seed:' line to set" >&2; exit 2; }
grep -q '^stop {' "$config" || { echo "bench_seeds: $config has no top-level 'stop {' block to replace" >&2; exit 2; }
if [ -n "$lines" ] && ! grep -q "^$block {" "$config"; then
  echo "bench_seeds: SET_LINES given but $config has no top-level '${block:-SET_BLOCK} {' block" >&2
  exit 2
fi
read -r -a seed_list <<<"$seeds"
read -r -a count_list <<<"$counts"
[ ${#seed_list[@]} -gt 0 ] && [ ${#count_list[@]} -gt 0 ] || { echo "bench_seeds: no seeds or no counts" >&2; exit 2; }
for s in "${seed_list[@]}"; do
  [[ $s =~ ^[0-9]+$ ]] || { echo "bench_seeds: seed '$s' is not a whole number" >&2; exit 2; }
done
mkdir -p "$out"
domain=${DOMAIN:-120}
config_dir=$(cd "$(dirname "$config")" && pwd)
for s in "${seed_list[@]}"; do
  if [ "${REPORT_ONLY:-0}" = 1 ]; then
    [ -r "$out/seed$s.txt" ] || { echo "bench_seeds: REPORT_ONLY but no run of seed $s in $out (seed$s.txt)" >&2; exit 2; }
    continue
  fi
  cfg="$out/seed$s.txtpb"
  # The seed line, the stop block (from its opening line to the first closing brace at column 0),
  # the added lines just inside SET_BLOCK's opening line, and a task of terms' model path made
  # absolute (it is relative to CONFIG's folder, and the copy lives in OUT_DIR).
  # SET_LINES' field names: a line of SET_BLOCK that sets one of them is dropped.
  awk -v seed="$s" -v stop="$stop" -v block="$block" -v lines="$lines" -v cdir="$config_dir" '
    BEGIN { n = split(lines, l, "\n"); for (i = 1; i <= n; i++) { f = l[i]; sub(/^[[:space:]]*/, "", f); sub(/[[:space:]]*[:{].*/, "", f); if (f != "") set[f] = 1 } }
    /^[[:space:]]*model: "[^\/]/ { sub(/model: "/, "model: \"" cdir "/"); print; next }
    /^seed:/ { print "seed: " seed; next }
    /^stop \{/ { skipping = 1; if ($0 ~ /\}[[:space:]]*$/) skipping = 0; print "stop { " stop " }"; next }
    skipping { if ($0 ~ /^\}/) skipping = 0; next }
    inblock && /^\}/ { inblock = 0 }
    inblock { f = $0; sub(/^[[:space:]]*/, "", f); sub(/[[:space:]]*[:{].*/, "", f); if (f in set) next }
    { print }
    block != "" && $0 ~ ("^" block " \\{") { inblock = 1; for (i = 1; i <= n; i++) print "  " l[i] }
  ' "$config" >"$cfg"
  if [ "${CONFIG_ONLY:-0}" = 1 ]; then
    echo "== seed $s: $cfg"
    continue
  fi
  echo "== seed $s: $cfg"
  DOMAIN=$domain bash "$here/bench_workers.sh" "$learner" "$worker" "$cfg" "$counts" "$out/seed$s" |
    tee "$out/seed$s.txt"
  domain=$((domain + ${#count_list[@]}))
  [ $((domain + ${#count_list[@]})) -le 232 ] || domain=20
done
[ "${CONFIG_ONLY:-0}" = 1 ] && exit 0

# The table, from bench_workers.sh's rows: workers, time to goal, wall, env steps, updates,
# updates/s, UTD, ...
echo
header="| seed |"
rule="|---|"
for c in "${count_list[@]}"; do header+=" $c workers |"; rule+="---|"; done
for c in "${count_list[@]:1}"; do header+=" $c / ${count_list[0]} |"; rule+="---|"; done
echo "$header"
echo "$rule"
declare -A within=() times=() ratio_of=() time_at=()
for s in "${seed_list[@]}"; do
  row="| $s |" first="" ratios=""
  for c in "${count_list[@]}"; do
    read -r t ups utd < <(awk -v c="$c" '$1 == c && $2 != "time" { print $2, $6, $7; exit }' "$out/seed$s.txt") || true
    t=${t:--} ups=${ups:-?} utd=${utd:-?}
    time_at["$s $c"]=$t
    row+=" $t s, $ups upd/s, UTD $utd |"
    times[$c]+="$t"$'\n'
    if [ "$c" = "${count_list[0]}" ]; then
      first=$t
    else
      # Printed to two places, kept unrounded for the median, counted against the bound unrounded.
      r=$(awk -v a="$t" -v b="$first" 'BEGIN { if (a == "-" || b == "-" || b + 0 <= 0) print "-"; else print a / b }')
      ratio_of[$c]+="$r"$'\n'
      [ "$r" = "-" ] || r=$(printf '%.2f' "$r")
      ratios+=" $r |"
      if [ "$r" != "-" ] && awk -v a="$t" -v b="$first" -v m="$bound" 'BEGIN { exit !(a / b <= m) }'; then
        within[$c]=$((${within[$c]:-0} + 1))
      fi
    fi
  done
  echo "$row$ratios"
done
median() {  # FORMAT; numbers on stdin, one per line ("-" skipped): their median, or "-"
  sort -n | awk -v f="$1" '$1 != "-" && $1 != "" { v[n++] = $1 }
    END { if (!n) print "-"; else printf f, (n % 2) ? v[(n - 1) / 2] : (v[n / 2 - 1] + v[n / 2]) / 2 }'
}
row="| median |" ratios=""
for c in "${count_list[@]}"; do
  row+=" $(printf '%s' "${times[$c]}" | median %.1f) s |"
done
for c in "${count_list[@]:1}"; do
  ratios+=" $(printf '%s' "${ratio_of[$c]}" | median %.2f) |"
done
echo "$row$ratios"
for c in "${count_list[@]:1}"; do
  echo "$c workers within $bound of ${count_list[0]} workers' time: ${within[$c]:-0} of ${#seed_list[@]} seeds"
done
# A sign test of the seeds' ratios against the bound: were the median ratio above it, a seed would
# fall within it with probability at most one half, so K or more of N within has probability at
# most P(Binomial(N, 1/2) >= K) (one-sided; a run that missed the goal counts as not within).
for c in "${count_list[@]:1}"; do
  awk -v k="${within[$c]:-0}" -v n="${#seed_list[@]}" -v c="$c" -v f="${count_list[0]}" -v b="$bound" 'BEGIN {
    p = 0
    for (i = k; i <= n; i++) { t = 1; for (j = 1; j <= i; j++) t *= (n - i + j) / j; p += t }
    printf "%s workers: median ratio to %s workers at most %s by a sign test over %d seeds: %d within, p = %.4f\n", c, f, b, n, k, p / 2 ^ n
  }'
done

# A run's training evaluations (label "eval", not the final one) from its learner's events
# (RUN/events.jsonl, "evaluation" events):
#   evaluations EVENTS curve METRIC  " VALUE@ASKED ...": METRIC "mean return" the mean return (to
#                                    0.1), another that metric's mean (to 0.001), and the seconds of
#                                    the run when it was asked (to 0.1); one without the value left out
#   evaluations EVENTS updates T     the updates made when the one asked at T s (to 0.1) was asked,
#                                    else "-"
evaluations() {
  python3 - "$@" <<'PY'
import json, sys
path, mode, arg = sys.argv[1:4]
found = []
for line in open(path, errors="replace"):
    try:
        e = json.loads(line)
    except ValueError:
        continue  # a line cut short by a killed run
    if e.get("event") == "evaluation" and e.get("label") == "eval" and e.get("asked_elapsed_s") is not None:
        found.append(e)
if mode == "curve":
    out = ""
    for e in found:
        v = e.get("mean") if arg == "mean return" else (e.get("metrics") or {}).get(arg)
        if v is not None:
            out += (" %.1f@%.1f" if arg == "mean return" else " %.3f@%.1f") % (v, e["asked_elapsed_s"])
    print(out)
else:
    at = [e["updates"] for e in found if "%.1f" % e["asked_elapsed_s"] == arg and e.get("updates") is not None]
    print(at[-1] if at else "-")
PY
}

# Each run's evaluations: the goal's metric (else the mean return) and the time it was asked.
metric=$(sed -n 's/.*metric: *"\([a-z_]*\)".*/\1/p' <<<"$stop")
metric=${metric:-mean return}
echo
echo "evaluations ($metric at the time asked):"
for s in "${seed_list[@]}"; do
  for c in "${count_list[@]}"; do
    events="$out/seed$s/w$c/learner/events.jsonl"
    evals=""
    if [ -r "$events" ]; then evals=$(evaluations "$events" curve "$metric"); fi
    echo "seed $s, $c workers:${evals:- none}"
  done
done

# The updates made when the goal's evaluation was asked (the learner's evaluation asked at the time
# to goal), per count in the seeds' order: whether more workers reached the goal with fewer updates
# or only with more updates per second. "-" where a run missed the goal or its events have no such
# evaluation.
echo
echo "updates when the goal's evaluation was asked:"
for c in "${count_list[@]}"; do
  list="" vals=""
  for s in "${seed_list[@]}"; do
    t=${time_at["$s $c"]} events="$out/seed$s/w$c/learner/events.jsonl" u="-"
    if [ "$t" != "-" ] && [ -r "$events" ]; then u=$(evaluations "$events" updates "$t"); fi
    list+=" $u"
    vals+="$u"$'\n'
  done
  echo "$c workers:$list (median $(printf '%s' "$vals" | median %.0f))"
done

# Whether each run kept the goal it reached (its events, not its log).
if [ -n "${GOAL_RETURN:-}" ]; then
  runs=()
  for s in "${seed_list[@]}"; do
    for c in "${count_list[@]}"; do runs+=("seed $s, $c workers=$out/seed$s/w$c/learner/events.jsonl"); done
  done
  echo
  python3 "$here/keep_report.py" --goal "$GOAL_RETURN" --within "${KEEP_WITHIN:-0.1}" "${runs[@]}"
fi
