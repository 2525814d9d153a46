#!/usr/bin/env bash
# The programs that run a trained policy from a checkpoint read its policy file (policy.bin,
# common/policy_file.h), so they link no LibTorch: fails when libtorch or libc10 is among a
# program's shared libraries or Torch's code is linked into it.
#   tests/unit/test_tools_link_no_torch.sh PROGRAM...
set -uo pipefail
[ $# -gt 0 ] || { echo "FAIL: no program given"; exit 1; }
failed=0
for p in "$@"; do
  prog=$(readlink -f "$p")
  [ -x "$prog" ] || { echo "FAIL: no program $p"; failed=1; continue; }
  libs=$(ldd "$prog") || { echo "FAIL: ldd $prog failed"; failed=1; continue; }
  if grep -E "libtorch|libc10" <<<"$libs"; then
    echo "FAIL: $(basename "$prog") links LibTorch (above, from ldd)"
    failed=1
  fi
  # Linked statically, LibTorch would bring its code in: tensors, the c10 core.
  symbols=$(nm -C "$prog" 2>/dev/null)
  [ -n "$symbols" ] || { echo "FAIL: nm found no symbols in $prog"; failed=1; continue; }
  if grep -E " (at::Tensor|c10::|torch::)" <<<"$symbols" | head -5 | grep .; then
    echo "FAIL: $(basename "$prog") holds LibTorch code (above, from nm)"
    failed=1
  fi
  echo "$(basename "$prog"): $(wc -l <<<"$libs") shared libraries"
done
[ "$failed" = 0 ] && echo "PASS: none of $# programs links LibTorch"
exit "$failed"
