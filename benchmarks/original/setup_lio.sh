#!/usr/bin/env bash
# Set up the original LIO code (011235813/lio) for timing beside pimbot.
#
# usage: benchmarks/original/setup_lio.sh LIO_CHECKOUT [VENV_DIR]
#
#   LIO_CHECKOUT  a checkout of 011235813/lio (the folder holding setup.py and lio/)
#   VENV_DIR      where to make the Python 3.7 venv
#                 (default: ${XDG_CACHE_HOME:-$HOME/.cache}/pimbot-original/lio-venv)
#
# What it does:
#   1. makes a venv with Python 3.7 (pyenv's 3.7.x, or $PYTHON37) and installs
#      tensorflow==1.15.5, protobuf==3.20.3 (newer protobuf breaks TF 1.15's generated
#      code) and gym==0.10.9 (the version the original README names), from PyPI;
#   2. applies the one import fix the original needs: lio/alg/lio_agent.py does
#      `import lio.alg.networks` / `import lio.utils.util` but then calls
#      `networks.…` / `util.…`; the fix turns those two lines into
#      `from lio.alg import networks` / `from lio.utils import util`.
#      The fix is applied IN PLACE to LIO_CHECKOUT (pass a copy if you want yours
#      untouched); it is idempotent.
# The checkout is not installed into the venv: the timing script puts it on sys.path.
set -euo pipefail

if [[ $# -lt 1 ]]; then
  awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"; exit 2
fi
LIO=$(cd "$1" && pwd)
VENV=${2:-${XDG_CACHE_HOME:-$HOME/.cache}/pimbot-original/lio-venv}
AGENT="$LIO/lio/alg/lio_agent.py"
[[ -f "$AGENT" ]] || { echo "not a 011235813/lio checkout: $AGENT missing" >&2; exit 1; }

# 1. the import fix (idempotent)
# (the file has CRLF line endings: the optional \r is kept as it is)
sed -i -E -e 's/^import lio\.alg\.networks(\r?)$/from lio.alg import networks\1/' \
          -e 's/^import lio\.utils\.util(\r?)$/from lio.utils import util\1/' "$AGENT"
grep -Eq $'^from lio.alg import networks\r?$' "$AGENT" && grep -Eq $'^from lio.utils import util\r?$' "$AGENT" \
  || { echo "import fix not applied: unexpected lio_agent.py" >&2; exit 1; }
echo "import fix applied: $AGENT"

# 2. the venv
PY=${PYTHON37:-}
if [[ -z "$PY" ]]; then
  for c in "$(pyenv root 2>/dev/null || echo "$HOME/.pyenv")"/versions/3.7*/bin/python3.7 \
           "$(command -v python3.7 || true)"; do
    [[ -x "$c" ]] && { PY=$c; break; }
  done
fi
[[ -n "$PY" ]] || { echo "no Python 3.7 found; set PYTHON37" >&2; exit 1; }
echo "python: $PY ($("$PY" --version 2>&1))"
if [[ ! -x "$VENV/bin/python" ]]; then
  "$PY" -m venv "$VENV"
fi
# PIP_CONSTRAINT from the environment is cleared: a machine-wide torch cap is irrelevant here.
PIP_CONSTRAINT= "$VENV/bin/python" -m pip install -q --upgrade 'pip<24' 'setuptools<68' wheel
PIP_CONSTRAINT= "$VENV/bin/python" -m pip install -q \
  tensorflow==1.15.5 protobuf==3.20.3 gym==0.10.9
"$VENV/bin/python" - <<'PY'
import tensorflow as tf, google.protobuf, gym, numpy
print("tensorflow", tf.__version__, "protobuf", google.protobuf.__version__,
      "gym", gym.__version__, "numpy", numpy.__version__)
PY
PYTHONPATH="$LIO" "$VENV/bin/python" -c "import lio.alg.lio_agent, lio.env.room_symmetric; print('lio imports ok')"
echo "venv: $VENV"
