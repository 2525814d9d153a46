#!/usr/bin/env bash
# Formats the project's C++ and CUDA files (tracked and new, not ignored) with clang-format and the
# .clang-format at the root. --check changes nothing and fails, naming the files, where the format
# differs (CI runs it).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
check=0
case "${1:-}" in
  --check) check=1 ;;
  "") ;;
  *) echo "usage: deploy/format.sh [--check]" >&2; exit 2 ;;
esac
CLANG_FORMAT="${CLANG_FORMAT:-$(command -v clang-format || command -v clang-format-14 || true)}"
if [ -z "$CLANG_FORMAT" ]; then
  echo "format: clang-format not found (deploy/install-deps.sh installs it)" >&2
  exit 2
fi
mapfile -t files < <(git ls-files --cached --others --exclude-standard -- '*.cpp' '*.h' '*.cu' | while read -r f; do
  [ -f "$f" ] && echo "$f"; done)
if [ "$check" = 0 ]; then
  "$CLANG_FORMAT" -i --style=file "${files[@]}"
  echo "format: ${#files[@]} files formatted with $("$CLANG_FORMAT" --version | head -1)"
  exit 0
fi
bad=()
for f in "${files[@]}"; do
  if ! "$CLANG_FORMAT" --style=file --dry-run --Werror "$f" >/dev/null 2>&1; then bad+=("$f"); fi
done
if [ ${#bad[@]} -gt 0 ]; then
  echo "format: ${#bad[@]} of ${#files[@]} files differ from .clang-format; run deploy/format.sh:" >&2
  printf '  %s\n' "${bad[@]}" >&2
  exit 1
fi
echo "format: ${#files[@]} files match .clang-format"
