#!/usr/bin/env bash
# The algorithms only learn: no source of learner/algorithms/ (its sub-folders included) includes a
# header of the bus, the roster, ingest, the publishers, the pacing or the learner's runner, directly
# or through a header of its own folder (the folder's own headers are followed; the others are
# Debian's, LibTorch's and common/'s config, model and policy types). And the interface they
# implement, algorithm.h, stays small: at most 80 lines. Fails naming the file and the header.
#   tests/unit/test_algorithms_include_no_farm.sh SOURCE_DIR
set -uo pipefail
src=$(readlink -f "$1")
dir=$src/learner/algorithms
[ -d "$dir" ] || { echo "FAIL: no folder $dir"; exit 1; }
forbidden='^(dds|trust|shm_leftovers|worker_roster|roster_thread|ingest|ingest_thread|spec_publisher|weight_publisher|eval_answer|evaluator|events|checkpoint|checkpointer|pacing|samples_per_insert|farm_service|farm_idl|farm|farmPubSubTypes)\.h$|^fastdds/|^fastrtps/|^fastcdr/'
failed=0
files=0
while IFS= read -r f; do
  files=$((files + 1))
  while read -r h; do
    if grep -Eq "$forbidden" <<<"$h"; then
      echo "FAIL: ${f#$src/} includes $h"
      failed=1
    fi
  done < <(sed -n 's/^[[:space:]]*#[[:space:]]*include[[:space:]]*[<"]\([^>"]*\)[>"].*/\1/p' "$f")
done < <(find "$dir" -type f \( -name '*.h' -o -name '*.cpp' -o -name '*.cu' \) | sort)
[ "$files" -gt 10 ] || { echo "FAIL: only $files sources found in $dir"; exit 1; }
lines=$(wc -l < "$dir/algorithm.h")
if [ "$lines" -gt 80 ]; then
  echo "FAIL: learner/algorithms/algorithm.h has $lines lines, more than 80"
  failed=1
fi
[ "$failed" = 0 ] && echo "PASS: none of $files sources of learner/algorithms includes the bus, roster, ingest or publishers"
exit "$failed"
