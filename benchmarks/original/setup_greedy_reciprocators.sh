#!/usr/bin/env bash
# Assemble the PIMbot code's Reciprocator Escape Room script (greedy_agent reciprocators/run_er.py)
# into a folder that run_original_reciprocator_er.py can run.
#
# usage: benchmarks/original/setup_greedy_reciprocators.sh GREEDY_RECIPROCATORS RECIPROCATOR_CHECKOUT \
#            GREEDY_CHECKOUT OUT
#
#   GREEDY_RECIPROCATORS   greedy_agent's reciprocators/ folder (a current clone of
#                          UCR-Intelligent-Robotics-Lab/greedy_agent has it; its commit a750298
#                          does not): run_er.py and src/agents/*.py
#   RECIPROCATOR_CHECKOUT  johnlyzhou/reciprocator (0a9c30a): the files greedy_agent's copy does
#                          not change (src/agents/voi.py, naive_learner.py, agent.py, utils.py,
#                          coins_voi.py, …)
#   GREEDY_CHECKOUT        greedy_agent at a750298 (or later): its lio/ package, whose
#                          room_symmetric.Env and config_room_lio the script imports
#   OUT                    the folder to make: OUT/reciprocators and OUT/lio (replaced)
#
# OUT/reciprocators is RECIPROCATOR_CHECKOUT with every file of GREEDY_RECIPROCATORS laid over it;
# OUT/lio is GREEDY_CHECKOUT/lio without its results/. Nothing is edited: the script runs as
# published, and run_original_reciprocator_er.py adds seeding, import stubs and an outside
# evaluation. OUT/SOURCES.txt lists every .py file of OUT with its SHA-256 and where it came from.
#
# The versions used for the runs in benchmarks/original/README.md ("Runs imported as evidence")
# are checked: a file of GREEDY_RECIPROCATORS with another SHA-256 is reported (not refused), so
# a rerun with a newer greedy_agent says what changed.
set -euo pipefail

if [[ $# -lt 4 ]]; then
  awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"; exit 2
fi
GR=$(cd "$1" && pwd)
REC=$(cd "$2" && pwd)
GA=$(cd "$3" && pwd)
OUT=$4
[[ -f "$GR/run_er.py" ]] || { echo "no run_er.py in $GR" >&2; exit 1; }
[[ -f "$REC/src/agents/voi.py" ]] || { echo "not a johnlyzhou/reciprocator checkout: $REC" >&2; exit 1; }
[[ -f "$GA/lio/env/room_symmetric.py" ]] || { echo "not a greedy_agent checkout: $GA" >&2; exit 1; }

# greedy_agent reciprocators/ files the evidence runs used (the versions the search index
# of this workplace holds; commit of each in parentheses)
declare -A USED=(
  [run_er.py]=c81d36795fd91dda31b4844912378f34121528e8c1027e7016ad48f55ba5cdfd                  # 0c21479
  [src/agents/components.py]=098c1f889f030af978d9b4608b43b306f8f2f32c06c687efbddff8b833e4fff1   # 51a295e
  [src/agents/memory.py]=a2d885b6dd363d616890c5f56f76080ec44e1b1c4f2753f44effa92c426663dc       # 51a295e
  [src/agents/ppo.py]=6e0067bbd727324780b6ec03c20167f2fee0b7f22eabc1efccb835cbadc1e05b          # 51a295e
  [src/agents/reciprocator.py]=c39ad6849e33a13145eb2d289ebff7f4cf467ffcb399aa5a5c34fcf9ca068872 # 51a295e
  [src/agents/target_functions.py]=474c46ee2518e051ed8ae053ed57f2bf4bceace022b0edef16d14cd6d0eecf0d # fa1881d
)

rm -rf "$OUT"
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
cp -r "$REC" "$OUT/reciprocators"
rm -rf "$OUT/reciprocators/.git"
(cd "$GR" && find . -name '*.py' -o -name '*.yaml' | sed 's|^\./||') | while read -r f; do
  mkdir -p "$OUT/reciprocators/$(dirname "$f")"
  cp "$GR/$f" "$OUT/reciprocators/$f"
done
mkdir -p "$OUT/lio"
(cd "$GA/lio" && tar --exclude=results -cf - .) | (cd "$OUT/lio" && tar -xf -)

for f in "${!USED[@]}"; do
  got=$(sha256sum "$OUT/reciprocators/$f" | cut -d' ' -f1)
  [[ "$got" == "${USED[$f]}" ]] || echo "note: reciprocators/$f differs from the version the evidence runs used" >&2
done
{
  echo "# sha256  path  origin"
  (cd "$OUT" && find reciprocators lio -name '*.py' | sort) | while read -r f; do
    rel=${f#reciprocators/}
    if [[ "$f" == lio/* ]]; then origin="greedy_agent $GA"
    elif [[ -f "$GR/$rel" ]]; then origin="greedy_agent reciprocators/ ($GR)"
    else origin="johnlyzhou/reciprocator ($REC)"; fi
    echo "$(sha256sum "$OUT/$f" | cut -d' ' -f1)  $f  $origin"
  done
} > "$OUT/SOURCES.txt"
echo "assembled: $OUT ($(grep -c greedy_agent\ reciprocators "$OUT/SOURCES.txt") files from greedy_agent reciprocators/)"
