#!/usr/bin/env bash
# A config received over the bus never names a file for a worker to write: a forged ExperimentSpec
# whose mCLARI config names a height-field PNG is refused by the worker with the field named, and
# no file appears; a learner whose own config names one writes none (it builds no task) and says
# so, publishes the spec without it, and its worker joins. Sizes are bounded before anything is allocated: a spec
# asking for a million steps per batch is refused, and so are --envs and --threads beyond their
# bounds; an experiment id that would name another folder is refused. A task of terms' model from the
# bus is never a path: a forged spec whose model, or one of its model files, names an absolute path
# or '..' is refused by the worker before anything is read, naming the path.
#   tests/integration/test_bus_config.sh LEARNER WORKER INTRUDER SOURCE_DIR
set -uo pipefail
learner=$(readlink -f "$1") worker=$(readlink -f "$2") intruder=$(readlink -f "$3") src=$(readlink -f "$4")
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init bus-config 113

# 1. The impostor's spec: a worker would write $dir/forged.png.
sed -e 's/experiment_id: "mclari_sac"/experiment_id: "it_forged"/' "$src/deploy/configs/mclari_sac.txtpb" >"$dir/forged.txtpb"
sed -i "0,/mclari {/s||mclari {\n    hfield_png: \"$dir/forged.png\"|" "$dir/forged.txtpb"
grep -q "hfield_png: \"$dir/forged.png\"" "$dir/forged.txtpb" || fail "test set-up: no hfield_png in the forged config"
"$intruder" --domain $domain --experiment it_forged --id impostor --obs 4 --act 2 --seconds 15 \
  --spec-config "$dir/forged.txtpb" >"$dir/impostor.log" 2>&1 & pids+=($!)
"$worker" --domain $domain --id bw --events "$dir/worker.jsonl" >"$dir/worker.log" 2>&1 & wp=$!; pids+=($wp)
wait_worker_event "$dir/worker.jsonl" join_failed 20 "hfield_png' names a file for this host to write" ||
  fail "the worker did not refuse the spec: $(tail -5 "$dir/worker.log")"
sleep 1
[ -e "$dir/forged.png" ] && fail "the worker wrote $dir/forged.png, named by a spec from the bus"
worker_events "$dir/worker.jsonl" joined | grep -qF '"experiment_id":"it_forged"' && fail "the worker joined the forged experiment"
kill -9 $wp 2>/dev/null; wait $wp 2>/dev/null

# 2. The learner's own config names one: the learner builds no task, so it writes none and says so;
#    the spec goes out without it and its worker joins.
domain2=$((domain + 1))
sed -e 's/experiment_id: "it_forged"/experiment_id: "it_own"/' -e "s|$dir/forged.png|$dir/own.png|" \
  -e 's/max_seconds: 1500/max_seconds: 10/' "$dir/forged.txtpb" >"$dir/own.txtpb"
"$learner" --config "$dir/own.txtpb" --run-dir "$dir/run" --domain $domain2 >"$dir/learner.log" 2>&1 & lp=$!; pids+=($lp)
"$worker" --domain $domain2 --id ow --envs 1 --events "$dir/worker2.jsonl" >"$dir/worker2.log" 2>&1 & pids+=($!)
wait_worker_event "$dir/worker2.jsonl" joined 30 '"experiment_id":"it_own"' || fail "the learner's worker did not join: $(tail -5 "$dir/worker2.log")"
grep -q "task.mclari.hfield_png names a file that a program building the task writes" "$dir/learner.log" ||
  fail "the learner did not say it leaves task.mclari.hfield_png to the programs that build the task"
[ -e "$dir/own.png" ] && fail "$dir/own.png was written: the learner builds no task, and a worker must not"

# 3. Sizes: a spec's steps per batch, the worker's flags.
sed -e "s|hfield_png: \"$dir/forged.png\"||" "$dir/forged.txtpb" >"$dir/huge.txtpb"
"$intruder" --domain $((domain + 2)) --experiment it_huge --id impostor2 --obs 4 --act 2 --seconds 15 \
  --spec-config "$dir/huge.txtpb" --spec-steps 1000000 >"$dir/impostor2.log" 2>&1 & pids+=($!)
"$worker" --domain $((domain + 2)) --id hw --events "$dir/worker3.jsonl" >"$dir/worker3.log" 2>&1 & pids+=($!)
wait_worker_event "$dir/worker3.jsonl" join_failed 20 "spec's steps_per_batch 1000000 x 4 envs is outside" ||
  fail "the worker did not refuse a million steps per batch: $(tail -5 "$dir/worker3.log")"
out=$(timeout 10 "$worker" --envs 100000 2>&1); rc=$?
[ $rc = 2 ] && grep -q -- "--envs: Value 100000 not in range 1 to 4096" <<<"$out" || fail "--envs 100000: rc $rc, '$out'"
out=$(timeout 10 "$worker" --threads 5000 2>&1); rc=$?
[ $rc = 2 ] && grep -q -- "--threads: Value 5000 not in range 1 to 256" <<<"$out" || fail "--threads 5000: rc $rc, '$out'"

# 4. An experiment id that would name another folder.
printf 'experiment_id: ".."\ntask { name: "pendulum" }\n' >"$dir/dots.txtpb"
out=$(timeout 20 "$learner" --config "$dir/dots.txtpb" --run-dir "$dir/dots" 2>&1); rc=$?
[ $rc = 2 ] && grep -q "is not a name for a run folder" <<<"$out" || fail "experiment_id \"..\": rc $rc, '$out'"

# 5. A task of terms whose bundled model names a path on the worker's host: the model file itself
#    (a real MJCF on this host, absolute) and a bundled file under '..'.
for n in 1 2; do
  if [ $n = 1 ]; then
    model="$src/deploy/configs/models/half_cheetah/half_cheetah.xml" file="$model"
  else
    model="robot.xml" file="../robot.xml"
  fi
  cat >"$dir/terms$n.txtpb" <<EOF
experiment_id: "it_terms$n"
task { name: "terms" terms {
  model: "$model"
  model_files { path: "$file" data: "<mujoco><worldbody><body><joint name='j' type='slide'/><geom size='0.1'/></body></worldbody><actuator><motor joint='j'/></actuator></mujoco>" }
  observation { term: "qpos" }
} }
EOF
  "$intruder" --domain $((domain + 3 + n)) --experiment it_terms$n --id impostor-t$n --obs 1 --act 1 --seconds 15 \
    --spec-config "$dir/terms$n.txtpb" >"$dir/impostor-t$n.log" 2>&1 & pids+=($!)
  "$worker" --domain $((domain + 3 + n)) --id tw$n --events "$dir/worker-t$n.jsonl" >"$dir/worker-t$n.log" 2>&1 &
  twp=$!; pids+=($twp)
  wait_worker_event "$dir/worker-t$n.jsonl" join_failed 20 "is an absolute path or leaves its folder" ||
    fail "the worker did not refuse a model naming '$file': $(tail -5 "$dir/worker-t$n.log")"
  worker_events "$dir/worker-t$n.jsonl" joined | grep -qF "\"experiment_id\":\"it_terms$n\"" &&
    fail "the worker joined a model naming '$file'"
  kill -9 $twp 2>/dev/null; wait $twp 2>/dev/null
done

farm_test_end
