#!/usr/bin/env bash
# dyngi launcher: sets up .venv (packages + the libLLVM runtime Dr.Jit needs) on first use, then
#   bash run.sh demo [--out DIR] [...]   the main job: a tour of the five papers, each vs its baseline (report.html)
#   bash run.sh test [pytest args]       the test suite (installs Debian's chromium for the browser tests)
#   bash run.sh dyngi ARGS...            any dyngi command
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
  for c in python3.11 python3 python; do
    if command -v "$c" >/dev/null 2>&1; then PY="$c"; break; fi
  done
fi
[ -n "$PY" ] || { echo "run.sh: error: no python3 found (Python >= 3.11 needed)" >&2; exit 2; }
"$PY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' \
  || { echo "run.sh: error: $PY is older than Python 3.11" >&2; exit 2; }

stamp=".venv/.dyngi-installed"
want="$(cat pyproject.toml | "$PY" -c 'import hashlib,sys; print(hashlib.sha256(sys.stdin.buffer.read()).hexdigest())')"
if [ ! -x .venv/bin/python ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "run.sh: setting up .venv (first run: about a minute) ..." >&2
  if ! "$PY" -m venv .venv 2>/dev/null; then
    "$PY" -m pip install -q --user virtualenv && "$PY" -m virtualenv -q .venv
  fi
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
  .venv/bin/python -m pip install -q -e ".[test]" 2>&1 | grep -v -i "warning" >&2 || true
  .venv/bin/python -c "import dyngi.backend" || { echo "run.sh: error: installation failed" >&2; exit 2; }
  echo "$want" > "$stamp"
fi

cmd="${1:-demo}"
shift || true

# Debian's chromium drives the viewer's browser tests (tests/viewer): installed for `test` when missing,
# as root where apt-get exists; tried once per .venv, and a failure only skips those tests
chrome_stamp=".venv/.dyngi-chromium-tried"
if [ "$cmd" = test ] && ! command -v chromium >/dev/null 2>&1 && [ ! -e "$chrome_stamp" ] \
   && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "run.sh: installing Debian's chromium for the viewer's browser tests (apt-get, once) ..." >&2
  if (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >/dev/null 2>&1; then
    echo "run.sh: chromium installed" >&2
  else
    echo "run.sh: warning: could not install chromium (apt-get failed); the browser tests will skip (under CI=true they fail)" >&2
  fi
  touch "$chrome_stamp" 2>/dev/null || true
fi
case "$cmd" in
  demo)  exec .venv/bin/dyngi demo "$@" ;;
  test)
    # two workers (pytest-xdist, one per core; whole files per worker so module fixtures are built once):
    # on a cold kernel cache most of the suite's time is single-threaded LLVM compilation.
    # DYNGI_TEST_WORKERS=0 runs in one process; an explicit -n / -p no:xdist in the arguments wins
    workers="${DYNGI_TEST_WORKERS:-2}"
    xd=()
    case " $* " in *" -n "*|*" -n="*|*"no:xdist"*) workers=0 ;; esac
    if [ "$workers" != 0 ] && .venv/bin/python -c "import xdist" 2>/dev/null; then
      xd=(-n "$workers" --dist loadfile --max-worker-restart 0)   # a crashed worker ends the run (no hang)
    fi
    exec .venv/bin/python -m pytest -q "${xd[@]}" "$@" ;;
  dyngi) exec .venv/bin/dyngi "$@" ;;
  *) echo "run.sh: error: unknown command '$cmd'; valid commands: demo, test, dyngi" >&2; exit 2 ;;
esac
