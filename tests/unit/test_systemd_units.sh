#!/usr/bin/env bash
# The shipped systemd units run as the unprivileged farm user inside systemd's sandbox (a spec from
# the bus or a hostile sample must not reach a root process with a writable system), and, where
# systemd-analyze is installed, they pass its check.
#   tests/unit/test_systemd_units.sh SOURCE_DIR
set -uo pipefail
src=$(readlink -f "$1")
failed=0
fail() { echo "FAIL: $*"; failed=1; }
n=0
for unit in "$src"/deploy/systemd/*.service; do
  n=$((n + 1))
  name=$(basename "$unit")
  for line in "User=farm" "Group=farm" "NoNewPrivileges=yes" "ProtectSystem=strict" "ProtectHome=yes" \
              "PrivateTmp=yes" "StateDirectory=farm" "CapabilityBoundingSet="; do
    grep -qx "$line" "$unit" || fail "$name: no '$line'"
  done
  grep -qE "^User=root" "$unit" && fail "$name: runs as root"
  # Everything it may write lies under /var/lib/farm or /var/log/farm.
  grep -E "^ReadWritePaths=" "$unit" | grep -vqE "^ReadWritePaths=(/var/lib/farm|/var/log/farm)( |$)" &&
    fail "$name: writable paths outside /var/lib/farm, /var/log/farm"
done
[ $n -ge 4 ] || fail "only $n units found"
grep -q "^FARM_RUN_DIR=/var/lib/farm/" "$src/deploy/systemd/learner.env.example" ||
  fail "learner.env.example: the run directory is not under /var/lib/farm (the unit's only writable folder)"
# The learner's unit resumes a run whose checkpoint survived in either place a crash can leave it
# (checkpoint/, or checkpoint.old/ when the crash came between the two renames of a save).
cond=$(grep -o '\$( \[ -e .* echo --resume )' "$src/deploy/systemd/farm-learner.service")
[ -n "$cond" ] || fail "farm-learner.service: no --resume condition found"
run=$(mktemp -d)
for layout in checkpoint checkpoint.old none; do
  rm -rf "$run"/*
  [ $layout = none ] || { mkdir -p "$run/$layout" && touch "$run/$layout/manifest.txtpb"; }
  got=$(FARM_RUN_DIR="$run" sh -c "echo $cond")
  want=--resume; [ $layout = none ] && want=""
  [ "$got" = "$want" ] || fail "farm-learner.service with only $layout/: '$got', expected '$want'"
done
rm -rf "$run"
if command -v systemd-analyze >/dev/null; then
  tmp=$(mktemp -d)
  for unit in "$src"/deploy/systemd/*.service; do
    # The binaries live in /opt/farm/bin on a farm host; verify the unit's syntax and directives.
    out=$(systemd-analyze verify "$unit" 2>&1 | grep -v -e "is not executable" -e "No such file" \
          -e "Failed to prepare filename" -e "Command .* is not executable" -e "Unit configuration has fatal error" \
          -e "EnvironmentFile" -e "^$" -e "Failed to create" -e "Failed to load" -e "ignoring: Invalid argument" || true)
    grep -qi "unknown\|invalid\|unrecognized" <<<"$out" && fail "$(basename "$unit"): systemd-analyze: $out"
  done
  rm -rf "$tmp"
else
  echo "systemd-analyze not installed: syntax check skipped"
fi
[ $failed = 0 ] && echo "PASS: $n units"
exit $failed
