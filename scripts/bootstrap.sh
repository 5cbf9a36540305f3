#!/usr/bin/env bash
# Prepare a fresh machine: a libLLVM that Dr.Jit can use, and a virtual
# environment (.venv) with sionna_mmir installed in editable mode.
# Idempotent: re-running it only does what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
VENV=${VENV:-.venv}

have_llvm() {
  "$PY" - <<'PYEOF'
import importlib.util, sys
spec = importlib.util.spec_from_file_location("b", "sionna_mmir/utils/backend.py")
b = importlib.util.module_from_spec(spec); spec.loader.exec_module(b)
sys.exit(0 if b.find_libllvm() else 1)
PYEOF
}

if ! have_llvm; then
  echo "[bootstrap] no libLLVM >= 16 found: installing Debian's libllvm19" >&2
  SUDO=""
  if [ "$(id -u)" != "0" ]; then
    if command -v sudo >/dev/null; then SUDO="sudo"; else
      echo "[bootstrap] need root to 'apt-get install libllvm19'; install it or set DRJIT_LIBLLVM_PATH" >&2
      exit 1
    fi
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19 >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
if [ ! -f "$VENV/.installed" ] || [ pyproject.toml -nt "$VENV/.installed" ]; then
  "$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
  "$VENV/bin/python" -m pip install -q -e ".[test,docs]"
  touch "$VENV/.installed"
fi
echo "[bootstrap] ready: $VENV" >&2
