#!/usr/bin/env bash
# Every program of the farm reads its options with CLI11 (common/cli.h): --help exits 0 and names
# its options; an unknown option and a bad number exit non-zero with an error on stderr that names
# the option (and the value). Every executable of ours in the build folder must be in the list
# below, so a new program cannot skip this. None of the calls gets past option parsing, so no DDS
# participant or simulation starts. Also fails when a source of a program walks argv by hand.
#   tests/unit/test_program_options.sh SOURCE_DIR BUILD_DIR
set -uo pipefail
src=$(readlink -f "$1")
build=$(readlink -f "$2")
failed=0
fail() {
  echo "FAIL: $*"
  failed=1
}

# PROGRAM|PATH under BUILD_DIR|OPTION with a bad value|VALUE|exit code of bad usage
programs="
farm-learner|learner/farm-learner|--domain|abc|2
farm-worker|worker/farm-worker|--envs|abc|2
farm-monitor|tools/farm-monitor|--interval|abc|2
farm-play|tools/farm-play|--fps|abc|2
farm-export|tools/farm-export|--seed|abc|1
farm-mclari-eval|tools/farm-mclari-eval|--episodes|abc|2
farm-mclari-sweep|tools/farm-mclari-sweep|--seconds|abc|2
farm-mobile-eval|tools/farm-mobile-eval|--episodes|abc|1
farm-policy-file|learner/farm-policy-file|checkpoint_dir|/no/such/dir|2
farm_intruder|tests/farm_intruder|--obs|abc|2
bench_a1_step|tests/bench_a1_step|--seconds|abc|2
bench_dqn|tests/bench_dqn|--batch|abc|2
bench_ingest|tests/bench_ingest|--senders|abc|2
bench_mclari|tests/bench_mclari|seconds|abc|2
bench_mobile|tests/bench_mobile|--seconds|abc|2
bench_offpolicy|tests/bench_offpolicy|--seconds|abc|2
bench_ppo|tests/bench_ppo|--threads|abc|2
bench_quadruped|tests/bench_quadruped|--seconds|abc|2
bench_sac|tests/bench_sac|--batch|abc|2
bench_scale|tests/bench_scale|--envs|abc|2
bench_transport|tests/bench_transport|--seconds|abc|2
bench_worker|tests/bench_worker|--envs|abc|2
discovery_participant|tests/discovery_participant|--expect|abc|2
farm_eval_actions|tests/farm_eval_actions|--episodes|abc|2
"

checked=0
listed=" "
while IFS='|' read -r name path opt value code; do
  [ -n "$name" ] || continue
  listed+="$name "
  prog=$build/$path
  [ -x "$prog" ] || continue  # not in this build (an option such as FARM_BUILD_BENCH is off)
  checked=$((checked + 1))

  out=$(timeout 20 "$prog" --help 2>&1)
  rc=$?
  [ $rc = 0 ] || fail "$name --help: exit $rc, '$out'"
  grep -qF -- "$opt" <<<"$out" || fail "$name --help does not name $opt: '$out'"

  err=$(timeout 20 "$prog" --no-such-option 2>&1 >/dev/null)
  rc=$?
  [ $rc = "$code" ] || fail "$name --no-such-option: exit $rc, expected $code"
  grep -qF -- "--no-such-option" <<<"$err" || fail "$name --no-such-option: stderr does not name it: '$err'"

  # A positional argument (no leading --) is given alone.
  if [ "${opt#--}" = "$opt" ]; then args=("$value"); else args=("$opt" "$value"); fi
  err=$(timeout 20 "$prog" "${args[@]}" 2>&1 >/dev/null)
  rc=$?
  [ $rc = "$code" ] || fail "$name ${args[*]}: exit $rc, expected $code"
  grep -qF -- "$opt" <<<"$err" && grep -qF -- "$value" <<<"$err" ||
    fail "$name ${args[*]}: stderr does not name $opt and $value: '$err'"
done <<<"$programs"
[ "$checked" -gt 0 ] || fail "none of the programs is in $build"

# Counts beyond what a program can hold are refused while parsing, naming the option, before any
# work: a plot of no episodes (a division by zero) and episode counts that only fail an allocation.
# PATH under BUILD_DIR|OPTION VALUE|the other options it needs|exit code of bad usage
ranges="
tools/farm-mobile-eval|--plot-episodes 0|--run-dir /no/such/run|1
tools/farm-mobile-eval|--plot-episodes -1|--run-dir /no/such/run|1
tools/farm-mobile-eval|--episodes 2147483647|--run-dir /no/such/run|1
tools/farm-mclari-eval|--episodes 100000|--config /no/such.txtpb --checkpoint /no/such|2
"
while IFS='|' read -r path arg others code; do
  [ -n "$path" ] && [ -x "$build/$path" ] || continue
  read -r opt value <<<"$arg"
  read -r -a rest <<<"$others"
  err=$(timeout 20 "$build/$path" "${rest[@]}" "$opt" "$value" 2>&1 >/dev/null)
  rc=$?
  [ $rc = "$code" ] || fail "$path $arg: exit $rc, expected $code: '$err'"
  grep -qF -- "$opt: Value $value not in range" <<<"$err" || fail "$path $arg: not refused as out of range: '$err'"
done <<<"$ranges"

# farm-learner --check FILE: a shipped config of a task in code, of a task of terms (its model
# files read) and of discrete actions loads and checks (exit 0, one line naming its experiment,
# task and algorithm; every shipped config loads in unit.test_config), writing nothing where it
# ran (no run folder: it stops before the farm starts); a config the loader refuses exits 2 with the error naming the file and the field, or
# the model file a task of terms misses. --config and --check go one at a time.
learner=$build/learner/farm-learner
if [ -x "$learner" ]; then
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
  mkdir "$work/cwd"
  for name in pendulum_sac hexapod_sac jetbot_dqn; do
    f=$src/deploy/configs/$name.txtpb
    id=$(sed -n 's/^experiment_id: "\(.*\)"$/\1/p' "$f")
    algo=$(sed -n 's/^algorithm: "\(.*\)"$/\1/p' "$f")
    out=$(cd "$work/cwd" && timeout 20 "$learner" --check "$f" 2>&1)
    rc=$?
    [ $rc = 0 ] || fail "farm-learner --check $f: exit $rc: '$out'"
    [[ "$out" =~ ^ok\ config=$f\ experiment=$id\ task=[a-z_0-9]+\ obs=[1-9][0-9]*\ act=[1-9][0-9]*\ actions=[0-9]+\ algorithm=$algo$ ]] ||
      fail "farm-learner --check $f: '$out'"
  done
  [ -z "$(ls -A "$work/cwd")" ] || fail "farm-learner --check wrote into its folder: $(ls -A "$work/cwd")"
  # name|what to do to a copy of a shipped config (in $work/bad)|what stderr must name
  bad="
pendulum_sac|echo 'no_such_field: 1' >>\$c|no_such_field
pendulum_sac|sed -i 's/^algorithm: .*/algorithm: \"no_such_algorithm\"/' \$c|no_such_algorithm
hexapod_sac|sed -i 's#models/hexapod/hexapod.xml#models/hexapod/missing.xml#' \$c|missing.xml
"
  while IFS='|' read -r name change what; do
    [ -n "$name" ] || continue
    rm -rf "$work/bad" && mkdir "$work/bad" && cp -r "$src/deploy/configs/models" "$work/bad/"
    c=$work/bad/$name.txtpb
    cp "$src/deploy/configs/$name.txtpb" "$c"
    eval "$change"
    err=$(timeout 20 "$learner" --check "$c" 2>&1 >/dev/null)
    rc=$?
    [ $rc = 2 ] || fail "farm-learner --check ($name: $change): exit $rc, expected 2: '$err'"
    grep -qF -- "$c" <<<"$err" && grep -qF -- "$what" <<<"$err" ||
      fail "farm-learner --check ($name: $change): stderr names not $c and $what: '$err'"
  done <<<"$bad"
  for args in "" "--config $c --check $c"; do
    err=$(timeout 20 "$learner" $args 2>&1 >/dev/null)
    rc=$?
    [ $rc = 2 ] || fail "farm-learner $args: exit $rc, expected 2: '$err'"
    grep -qF -- "--check" <<<"$err" && grep -qF -- "--config" <<<"$err" ||
      fail "farm-learner $args: stderr names not --config and --check: '$err'"
  done
fi

# Every executable of ours in the build folder is listed: ELF files outside CMake's own folders
# and the fuzz build; the gtest programs (test_*) take gtest's options, not ours.
while IFS= read -r f; do
  name=$(basename "$f")
  case "$name" in test_* | *.so | *.so.*) continue ;; esac
  head -c 4 "$f" | grep -q "ELF" || continue
  [[ "$listed" == *" $name "* ]] || fail "$f is a program of the build that this test does not check: add it"
done < <(find "$build" -type f -perm -u+x -not -path "*/CMakeFiles/*" -not -path "$build/fuzz-build/*" \
  -not -path "$build/_deps/*")

# No program walks argv by hand: CLI11 reads the options (farm::cli::parse gets argc and argv whole).
# Comment lines may name argv[0].
hits=$(cd "$src" && grep -rn --include=*.cpp --include=*.h 'argv\[' learner worker tools tests/bench tests/integration common |
  grep -vE '^[^:]+:[0-9]+:[[:space:]]*//')
[ -z "$hits" ] || fail "argv read by hand (use CLI11, common/cli.h):"$'\n'"$hits"

[ "$failed" = 0 ] && echo "PASS: $checked programs: --help, an unknown option and a bad value; no argv read by hand"
exit "$failed"
