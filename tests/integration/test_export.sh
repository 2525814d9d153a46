#!/usr/bin/env bash
# farm-export: a SAC (pendulum, tests/data/checkpoint_v1), a PPO (cart-pole, the same fixtures,
# observation normalizer on), a PPO with ELU hidden layers (cart-pole, from a run of a learner and a
# worker here: the ELU network crosses DDS and runs in the worker) and DQN policies (Jetbot, from
# runs here too: the initial network, and one trained for 10 s, with its best) exported as ONNX
# (the ELU one with Elu nodes); onnx.checker
# accepts each model and OpenCV's DNN module computes from 1,000 observations of real episodes the
# actions the worker's Eigen policy took there (within 1e-5; DQN: the same argmax, Q values within
# 1e-5). The fixtures predate policy files: farm-policy-file writes theirs first. Bad input gets an
# error naming what was wrong.
#   tests/integration/test_export.sh EXPORT LEARNER WORKER SOURCE_DIR POLICY_FILE
set -uo pipefail
export_bin=$(readlink -f "$1") learner=$(readlink -f "$2") worker=$(readlink -f "$3") src=$(readlink -f "$4")
policy_file=$(readlink -f "$5")
data=$src/tests/data/checkpoint_v1
check=$src/tests/integration/check_onnx_export.py
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
farm_test_init export 181
# Debian's python3 holds python3-onnx and python3-opencv (another python3 may come first on PATH).
py=python3
[ -x /usr/bin/python3 ] && py=/usr/bin/python3
"$py" -c "import cv2, onnx" 2>/dev/null || { echo "SKIP: $py lacks cv2 or onnx (python3-opencv, python3-onnx)"; exit 77; }

# start_run NAME: the learner of $dir/NAME.txtpb and one worker, in the background ($lp).
start_run() {
  "$learner" --config "$dir/$1.txtpb" --run-dir "$dir/$1" --domain $domain >"$dir/$1.log" 2>&1 & lp=$!
  pids+=($lp)
  "$worker" --domain $domain --experiment it_export_$1 --id export-$1 >"$dir/$1-worker.log" 2>&1 & pids+=($!)
}
# dqn_run NAME DQN_FIELDS STOP: a Jetbot DQN run, learner and one worker, in the background ($lp).
dqn_run() {
  cat >"$dir/$1.txtpb" <<CFG
experiment_id: "it_export_$1"
algorithm: "dqn"
task { name: "jetbot" jetbot { scene { discrete_actions: true physics_dt: 0.01 control_substeps: 10 max_episode_steps: 100 } } }
dqn { hidden: 32 hidden: 32 buffer_size: 20000 batch_size: 32 publish_every_updates: 5 schedule_env_steps: 4000 $2 }
worker { envs_per_worker: 4 steps_per_batch: 25 max_batches_per_version: 4 }
eval { episodes: 2 every_seconds: 3 final_episodes: 2 }
checkpoint_every_seconds: 600
log_every_seconds: 1
stop { $3 }
CFG
  start_run "$1"
}
# The initial network (no update: learning_starts beyond the run; torch seeded by the config's
# seed, so the same weights on every machine), whose greedy actions vary over the observations
# (4 of the 7 in 1,000 steps): the argmax head is compared where it picks different actions.
dqn_run dqn_initial "learning_starts: 20000" "max_env_steps: 1000 max_seconds: 60"
wait $lp || fail "dqn_initial learner exited $?: $(tail -5 "$dir/dqn_initial.log")"
# PPO with ELU hidden layers on cart-pole (the fixture's setup): 16 fits, the weights of each
# version sent to the worker over DDS and run there.
ppo_elu_steps=16384
cat >"$dir/ppo_elu.txtpb" <<CFG
experiment_id: "it_export_ppo_elu"
algorithm: "ppo"
task { name: "cartpole" cartpole { control_substeps: 2 max_episode_steps: 100 } }
ppo { activation: "elu" steps_per_fit: 1024 mini_batch_size: 256 hidden: 16 hidden: 16 eval_every_fits: 4 }
worker { envs_per_worker: 8 steps_per_batch: 32 max_batches_per_version: 4 }
eval { episodes: 2 final_episodes: 2 }
checkpoint_every_seconds: 600
log_every_seconds: 1
stop { max_env_steps: $ppo_elu_steps max_seconds: 60 }
CFG
start_run ppo_elu
wait $lp || fail "ppo_elu learner exited $?: $(tail -5 "$dir/ppo_elu.log")"
elu_steps=$(sed -n 's/^env_steps: \([0-9]*\)$/\1/p' "$dir/ppo_elu/checkpoint/manifest.txtpb" 2>/dev/null)
[ "${elu_steps:-0}" -ge $ppo_elu_steps ] ||
  fail "ppo_elu: the worker ran ${elu_steps:-no} steps of the ELU policy, expected $ppo_elu_steps: $(tail -3 "$dir/ppo_elu-worker.log")"
# A policy trained for 10 s (some thousand updates): it may keep to one or two actions.
dqn_run dqn "learning_starts: 200" "max_seconds: 10"
mkdir -p "$dir/sac" "$dir/ppo"
cp -r "$data/sac/checkpoint" "$dir/sac/checkpoint"
cp -r "$data/ppo/checkpoint" "$dir/ppo/checkpoint"
for name in sac ppo; do
  "$policy_file" "$dir/$name/checkpoint" >"$dir/$name-policy-file.log" 2>&1 ||
    fail "$name: farm-policy-file exited $?: $(cat "$dir/$name-policy-file.log")"
  [ -s "$dir/$name/checkpoint/policy.bin" ] || fail "$name: farm-policy-file wrote no policy.bin"
done

# export NAME ALGORITHM MIN_DISTINCT [--best]: the model and 1,000 recorded steps, then the
# comparison (DQN: at least MIN_DISTINCT different actions among the 1,000).
export_and_check() {
  local name=$1 algorithm=$2 min_distinct=$3
  shift 3
  "$export_bin" --run-dir "$dir/$name" "$@" --out "$dir/$name.onnx" --record 1000 "$dir/$name.csv" --seed 11 \
    >"$dir/$name-export.log" 2>&1 || { fail "$name: farm-export exited $?: $(cat "$dir/$name-export.log")"; return; }
  cat "$dir/$name-export.log"
  "$py" "$check" "$dir/$name.onnx" "$dir/$name.csv" "$algorithm" 1e-5 "$min_distinct" ||
    fail "$name: the ONNX model does not act as the worker"
}
export_and_check sac sac 0
export_and_check ppo ppo 0
export_and_check ppo_elu ppo 0
"$py" - "$dir/ppo_elu.onnx" <<'PY' || fail "ppo_elu: the model's activations are not Elu with alpha 1"
import sys, onnx
m = onnx.load(sys.argv[1])
acts = [n for n in m.graph.node if n.op_type in ("Elu", "Relu", "Tanh")]
print("ppo_elu: activation nodes", [(n.op_type, [a.f for a in n.attribute if a.name == "alpha"]) for n in acts])
sys.exit(0 if len(acts) == 2 and all(n.op_type == "Elu" and [a.f for a in n.attribute] == [1.0] for n in acts) else 1)
PY

wait $lp || fail "dqn learner exited $?: $(tail -5 "$dir/dqn.log")"
export_and_check dqn_initial dqn 2
export_and_check dqn dqn 1
if [ -f "$dir/dqn/best/manifest.txtpb" ]; then
  mkdir -p "$dir/dqnbest" && cp -r "$dir/dqn/best" "$dir/dqnbest/best"
  export_and_check dqnbest dqn 1 --best
else
  fail "the dqn run kept no best policy: $(grep -i best "$dir/dqn.log" | tail -3)"
fi

# expect_error WHAT TEXT ARGS...: farm-export exits 1 and its error holds TEXT.
expect_error() {
  local what=$1 text=$2
  shift 2
  local out rc
  out=$("$export_bin" "$@" 2>&1); rc=$?
  echo "$what: $out"
  [ $rc = 1 ] || fail "$what: exit code $rc, expected 1"
  grep -qF -- "$text" <<<"$out" || fail "$what: the error does not say '$text'"
}
mkdir -p "$dir/empty"
expect_error "folder without a policy" "holds no policy: $dir/empty/checkpoint/manifest.txtpb does not exist" \
  --run-dir "$dir/empty" --out "$dir/x.onnx"
expect_error "no such folder" "run folder $dir/nowhere does not exist" --run-dir "$dir/nowhere" --out "$dir/x.onnx"
expect_error "best of a run without one" "leave out --best" --run-dir "$dir/sac" --best --out "$dir/x.onnx"
# An algorithm no learner knows, in the manifest's experiment config.
mkdir -p "$dir/unknown" && cp -r "$data/sac/checkpoint" "$dir/unknown/checkpoint"
sed -i 's/^config_text: "/config_text: "algorithm: \\"a2c\\"\\n/' "$dir/unknown/checkpoint/manifest.txtpb"
expect_error "unknown algorithm" 'expected one of: sac, dqn, ppo, td3, fastsac; got "a2c"' --run-dir "$dir/unknown" --out "$dir/x.onnx"
# A checkpoint of a learner that wrote no policy file: the error says how to write it.
mkdir -p "$dir/old" && cp -r "$data/sac/checkpoint" "$dir/old/checkpoint"
expect_error "no policy file" "$dir/old/checkpoint/policy.bin does not exist" --run-dir "$dir/old" --out "$dir/x.onnx"
expect_error "no policy file" "with \`farm-policy-file $dir/old/checkpoint\`" --run-dir "$dir/old" --out "$dir/x.onnx"
# A policy file that is not one, and one of another task's network.
cp "$dir/sac/checkpoint/policy.bin" "$dir/sac-policy.bin"
head -c 100 /dev/urandom >"$dir/old/checkpoint/policy.bin"
expect_error "garbled policy file" "policy file $dir/old/checkpoint/policy.bin: not a PolicyFile" --run-dir "$dir/old" --out "$dir/x.onnx"
mkdir -p "$dir/foreign" && cp -r "$dir/sac/checkpoint" "$dir/foreign/checkpoint"
cp "$dir/ppo/checkpoint/policy.bin" "$dir/foreign/checkpoint/policy.bin"
expect_error "policy of another task" "does not fit task pendulum" --run-dir "$dir/foreign" --out "$dir/x.onnx"
# farm-policy-file on a manifest without the networks it names.
mkdir -p "$dir/nonet" && cp -r "$data/sac/checkpoint" "$dir/nonet/checkpoint" && rm "$dir/nonet/checkpoint/sac/sac.pt"
out=$("$policy_file" "$dir/nonet/checkpoint" 2>&1); rc=$?
[ $rc = 1 ] && grep -qF "$dir/nonet/checkpoint/sac/sac.pt does not exist" <<<"$out" ||
  fail "farm-policy-file without networks: rc $rc, '$out'"
[ -e "$dir/nonet/checkpoint/policy.bin" ] && fail "farm-policy-file without networks wrote a policy file"
# A manifest that is not one: text that does not parse, and a file far bigger than any manifest.
mkdir -p "$dir/garbled/checkpoint" && echo 'policy_version: "x" {' >"$dir/garbled/checkpoint/manifest.txtpb"
expect_error "garbled manifest" "manifest.txtpb:1:17: Expected integer, got: \"x\" (not a checkpoint manifest)" --run-dir "$dir/garbled" --out "$dir/x.onnx"
mkdir -p "$dir/huge/checkpoint" && truncate -s 20M "$dir/huge/checkpoint/manifest.txtpb"
expect_error "oversized manifest" "bytes, more than a manifest's limit of 16777216" --run-dir "$dir/huge" --out "$dir/x.onnx"
expect_error "bad --record" "--record: Value -5 not in range 1 to 10000000" --run-dir "$dir/sac" --out "$dir/x.onnx" --record -5 "$dir/r.csv"
[ -e "$dir/x.onnx" ] && fail "a failed export left $dir/x.onnx"

farm_test_end "farm-export: SAC, PPO (tanh and ELU) and DQN models act as the worker under OpenCV's DNN"
