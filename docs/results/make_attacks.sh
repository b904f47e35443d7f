#!/usr/bin/env bash
# Reproduces docs/results/attacks.md, attacks.csv and the figures fig1–fig5: clean LIO
# and every attack on ER(2,1), ER(4,2), ER(4,3) and the 2-player IPD, 10 seeds each
# (about 25 minutes on 2 CPU cores). Run from the repository root; finished runs are
# skipped and interrupted ones resumed.
#
# N ≥ 3 runs use the original code's shared incentive updates (README, Decisions):
# without them clean LIO does not solve ER(4,2) or ER(4,3), and the paper's numbers
# come from the original code.
set -euo pipefail
RUNS=${RUNS:-runs/attacks}

declare -A ENV_ARGS=(
  [er21]="escape_room-v0 --iterations 50000"
  [er42]="escape_room-v0 n_agents=4 min_at_lever=2 --iterations 25000 --hp original_shared_incentive_updates=true"
  [er43]="escape_room-v0 n_agents=4 min_at_lever=3 --iterations 25000 --hp original_shared_incentive_updates=true"
  [ipd]="ipd-v0 --iterations 20000 --eval-period 500"
)
declare -A ATTACK_ARGS=(
  [clean]=""
  [self_centered]="--attack self_centered"
  [fake_incentive]="--attack fake_incentive"
  [bypass]="--attack bypass"
  [reverse]="--attack reverse"
  [admo_stealthy]="--attack admo --ap mode=stealthy"
  [admo_disrupt]="--attack admo --ap mode=disrupt"
)
for env in er21 er42 er43 ipd; do
  for attack in clean self_centered fake_incentive bypass reverse admo_stealthy admo_disrupt; do
    # shellcheck disable=SC2086
    pimbot train ${ENV_ARGS[$env]} ${ATTACK_ARGS[$attack]} --seeds 10 --quiet \
      --out "$RUNS/${env}_${attack}"
  done
done
python -m pimbot.analysis.attack_results "$RUNS" docs/results
