#!/usr/bin/env bash
# episcatter set-up on a fresh machine (see README "Install"):
#  1. an LLVM that Dr.Jit's LLVM backend can run with (>= 16; Debian/Ubuntu
#     machines often carry only 14/15, which Dr.Jit refuses or crashes on):
#     Debian's libllvm19 when we may use apt (root or passwordless sudo),
#     else the PyPI wheel karellen-llvm-core (no root needed);
#  2. the package itself, editable, with its test extras.
# Safe to run again: steps already done are skipped.
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3}

usable_system_llvm() {
  { ls /usr/lib/*/libLLVM*.so* /usr/lib/libLLVM*.so* /usr/lib/llvm-*/lib/libLLVM*.so* 2>/dev/null || true; } \
    | grep -Eq 'LLVM([-.]|\.so\.)?(1[6-9]|[2-9][0-9])'
}

if usable_system_llvm; then
  echo "install.sh: found a system libLLVM >= 16"
else
  SUDO=""
  [ "$(id -u)" = 0 ] || { command -v sudo >/dev/null && sudo -n true 2>/dev/null && SUDO="sudo"; } || true
  if command -v apt-get >/dev/null && { [ "$(id -u)" = 0 ] || [ -n "$SUDO" ]; }; then
    echo "install.sh: installing Debian's libllvm19 for Dr.Jit"
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get install -y -qq libllvm19 >/dev/null 2>&1 \
      || { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libllvm19; }
  else
    echo "install.sh: no root: installing LLVM from PyPI (karellen-llvm-core)"
    "$PY" -m pip install -q karellen-llvm-core
  fi
fi

"$PY" -m pip install -q -e ".[test]"
# Fails with the fix spelled out if Dr.Jit still cannot use the LLVM it finds.
"$PY" -c "import integrators, drjit; print('install.sh: Dr.Jit uses LLVM', '.'.join(map(str, drjit.detail.llvm_version())))"
