#!/usr/bin/env bash
# The algorithms only learn: no source of learner/algorithms/ includes a header of the bus, the
# roster, ingest, the publishers or the learner's farm side, directly or through a header of its own
# folder (the folder's own headers are followed; the others are Debian's, LibTorch's and common/'s
# config, model and policy types). Fails naming the file and the header.
#   tests/unit/test_algorithms_include_no_farm.sh SOURCE_DIR
set -uo pipefail
src=$(readlink -f "$1")
dir=$src/learner/algorithms
[ -d "$dir" ] || { echo "FAIL: no folder $dir"; exit 1; }
forbidden='^(dds|trust|shm_leftovers|worker_roster|roster_thread|ingest|ingest_thread|spec_publisher|eval_answer|events|checkpoint|farm_service|farm_idl|farm|farmPubSubTypes)\.h$|^fastdds/|^fastrtps/|^fastcdr/'
failed=0
files=0
for f in "$dir"/*.h "$dir"/*.cpp "$dir"/*.cu; do
  [ -e "$f" ] || continue
  files=$((files + 1))
  while read -r h; do
    if grep -Eq "$forbidden" <<<"$h"; then
      echo "FAIL: ${f#$src/} includes $h"
      failed=1
    fi
  done < <(sed -n 's/^[[:space:]]*#[[:space:]]*include[[:space:]]*[<"]\([^>"]*\)[>"].*/\1/p' "$f")
done
[ "$files" -gt 10 ] || { echo "FAIL: only $files sources found in $dir"; exit 1; }
[ "$failed" = 0 ] && echo "PASS: none of $files sources of learner/algorithms includes the bus, roster, ingest or publishers"
exit "$failed"
