#!/usr/bin/env bash
# Apply patches/*.patch to a temporary copy of the installed `sionna` package
# and run every reproduction in patches/repro/ twice:
#   installed sionna-rt           --expect bug
#   patched copy (via PYTHONPATH) --expect fixed   (--expect bug where no patch)
# Never touches the installed package.
#
# Usage: patches/check.sh [--keep] [NNNN ...]   (default: all numbers)
#   PYTHON=/path/to/python  interpreter (default: .venv/bin/python, else python3)
#   --keep                  keep the patched copy and print where it is
set -u

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
PATCHES="$ROOT/patches"
PY=${PYTHON:-$ROOT/.venv/bin/python}
[ -x "$PY" ] || PY=$(command -v python3)

KEEP=0
ONLY=()
for a in "$@"; do
    case "$a" in
        --keep) KEEP=1 ;;
        -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
        *) ONLY+=("$a") ;;
    esac
done

if ! command -v patch >/dev/null 2>&1; then
    echo "check.sh: the 'patch' executable is missing (apt-get install patch)" >&2
    exit 2
fi

# Location and version of the installed package (not importing it, and
# ignoring any PYTHONPATH that could point at a patched copy)
read -r SRC VERSION < <(env -u PYTHONPATH "$PY" - <<'EOF'
import importlib.metadata, importlib.util
spec = importlib.util.find_spec("sionna")
print(spec.submodule_search_locations[0], importlib.metadata.version("sionna-rt"))
EOF
)
if [ -z "${SRC:-}" ] || [ ! -d "$SRC/rt" ]; then
    echo "check.sh: no installed sionna-rt found for $PY" >&2
    exit 2
fi
echo "installed sionna-rt $VERSION at $SRC"
[ "$VERSION" = "2.2.0" ] || echo "warning: the patches were made against sionna-rt 2.2.0"

WORK=$(mktemp -d "${TMPDIR:-/tmp}/sionna-patched.XXXXXX")
if [ "$KEEP" = 1 ]; then
    echo "patched copy kept at $WORK (use PYTHONPATH=$WORK)"
else
    trap 'rm -rf "$WORK"' EXIT
fi
cp -r "$SRC" "$WORK/sionna"
find "$WORK/sionna" -name __pycache__ -prune -exec rm -rf {} +

FAILED=()
# 1. apply: dry run first, then for real, each in order; any fuzz/offset is a failure
for p in "$PATCHES"/[0-9][0-9][0-9][0-9]-*.patch; do
    name=$(basename "$p")
    if ! out=$(cd "$WORK" && patch -p1 --dry-run --batch < "$p" 2>&1) \
        || grep -Eqi 'fuzz|offset|fail|reversed|malformed|garbage' <<<"$out"; then
        echo "FAIL apply $name (dry run):"; echo "$out" | sed 's/^/    /'
        FAILED+=("apply $name"); continue
    fi
    if ! out=$(cd "$WORK" && patch -p1 --batch --no-backup-if-mismatch < "$p" 2>&1); then
        echo "FAIL apply $name:"; echo "$out" | sed 's/^/    /'
        FAILED+=("apply $name"); continue
    fi
    echo "PASS apply $name"
done

# 2. reproductions
run() {  # run <label> <expect> <pythonpath or ''> <script>
    local label=$1 expect=$2 pp=$3 script=$4 out rc
    if [ -n "$pp" ]; then
        out=$(cd "$ROOT" && PYTHONPATH="$pp" "$PY" "$script" --expect "$expect" 2>&1); rc=$?
    else
        out=$(cd "$ROOT" && env -u PYTHONPATH "$PY" "$script" --expect "$expect" 2>&1); rc=$?
    fi
    local line
    line=$(grep -E '^(PASS|FAIL) ' <<<"$out" | tail -n 1)
    if [ "$rc" = 0 ] && [ "${line:0:4}" = PASS ]; then
        echo "  [$label] $line"
    else
        echo "  [$label] FAIL (exit status $rc):"; echo "$out" | tail -n 15 | sed 's/^/      /'
        FAILED+=("$label $(basename "$script")")
    fi
}

for r in "$PATCHES"/repro/[0-9][0-9][0-9][0-9]_*.py; do
    num=$(basename "$r" | cut -c1-4)
    if [ "${#ONLY[@]}" -gt 0 ] && ! printf '%s\n' "${ONLY[@]}" | grep -qx "$num"; then
        continue
    fi
    echo "== $(basename "$r")"
    if compgen -G "$PATCHES/$num-*.patch" >/dev/null; then
        run installed bug "" "$r"
        run patched fixed "$WORK" "$r"
    else
        # No patch for this one: the limitation is expected in both
        run installed bug "" "$r"
        run patched bug "$WORK" "$r"
    fi
done

if [ "${#FAILED[@]}" -gt 0 ]; then
    echo "check.sh: ${#FAILED[@]} failure(s): ${FAILED[*]}"
    exit 1
fi
echo "check.sh: all patches apply and every reproduction behaves as expected"
