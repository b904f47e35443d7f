#!/usr/bin/env bash
# Set up the original Reciprocator code (johnlyzhou/reciprocator) for timing beside pimbot.
#
# usage: benchmarks/original/setup_reciprocator.sh RECIPROCATOR_CHECKOUT [VENV_DIR]
#
#   RECIPROCATOR_CHECKOUT  a checkout of johnlyzhou/reciprocator (holding src/ and configs/)
#   VENV_DIR               where to make the venv
#                          (default: ${XDG_CACHE_HOME:-$HOME/.cache}/pimbot-original/reciprocator-venv)
#
# Environment:
#   PYTHON       the interpreter for the venv (default: python3; the original pins torch 2.1.2,
#                which has wheels for Python 3.8-3.11)
#   TORCH_SPEC   the torch requirement (default: torch==2.13.0, the CPU build that lies on this
#                workplace's disk for Python 3.11; elsewhere PyPI's wheel is taken, run on the CPU).
#                TORCH_SPEC=torch==2.1.2 gives the original's pinned version (a large download).
#
# Only PyPI is used. The checkout is not changed and not installed: the timing driver
# imports src.training.ipd_trainer with the checkout on sys.path. Only what the IPD
# trainer imports is installed (torch, numpy, omegaconf, tqdm), not the whole
# requirements.txt (lightning, pygame, matplotlib are for the other games and plots).
set -euo pipefail

if [[ $# -lt 1 ]]; then
  awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"; exit 2
fi
REC=$(cd "$1" && pwd)
VENV=${2:-${XDG_CACHE_HOME:-$HOME/.cache}/pimbot-original/reciprocator-venv}
[[ -f "$REC/src/training/ipd_trainer.py" && -f "$REC/configs/ipd.yaml" ]] \
  || { echo "not a johnlyzhou/reciprocator checkout: $REC" >&2; exit 1; }
PY=${PYTHON:-python3}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}

if [[ ! -x "$VENV/bin/python" ]]; then
  "$PY" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q "$TORCH_SPEC" 'numpy<2.5' omegaconf tqdm
PYTHONPATH="$REC" "$VENV/bin/python" - <<'PY'
import torch, numpy, omegaconf
from src.training.ipd_trainer import IPDTrainer  # noqa: F401
print("torch", torch.__version__, "numpy", numpy.__version__, "omegaconf", omegaconf.__version__)
print("reciprocator imports ok")
PY
echo "venv: $VENV"
