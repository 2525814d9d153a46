#!/usr/bin/env bash
# farm-learner steps no simulation: evaluations run on the workers, so the learner links neither
# MuJoCo nor the robots (docs/guides/evaluation.md). Fails when libmujoco is among its
# shared libraries or a robot's or MuJoCo's code is linked into it.
#   tests/unit/test_learner_links_no_mujoco.sh FARM_LEARNER
set -uo pipefail
learner=$(readlink -f "$1")
[ -x "$learner" ] || { echo "FAIL: no program $1"; exit 1; }
failed=0
libs=$(ldd "$learner") || { echo "FAIL: ldd $learner failed"; exit 1; }
if grep -i "mujoco" <<<"$libs"; then
  echo "FAIL: farm-learner links MuJoCo (above, from ldd)"
  failed=1
fi
# Linked statically, a robot would bring its code in: the task factory, the MuJoCo calls.
symbols=$(nm -C "$learner" 2>/dev/null)
[ -n "$symbols" ] || { echo "FAIL: nm found no symbols in $learner"; exit 1; }
if grep -E "farm::robots::make_task|farm::evaluate_policy| mj_step$| mj_makeData$" <<<"$symbols" | head -5 | grep .; then
  echo "FAIL: farm-learner holds simulation code (above, from nm)"
  failed=1
fi
[ "$failed" = 0 ] && echo "PASS: $(wc -l <<<"$libs") shared libraries, none of them MuJoCo; no simulation code"
exit "$failed"
