#!/usr/bin/env bash
# Regenerates docs/robot from the trained Escape Room run directories (SUITE/attacks/er*_*,
# made by the attack experiments): the harsh-physics table (robot_harsh.md), the rendered
# frames and episode GIF, and the throughput benchmark. The nominal physics-vs-abstract
# table is the report's robot section (the suite's robot/* jobs). About 15 min on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/../.."
. .venv/bin/activate
RUNS=${1:-runs/attacks}
OUT=${2:-runs/robot}
# The same policies under harsh physics (6x actuation noise, 5x odometry noise, 15 s per decision).
python -m pimbot.robot.results "$RUNS" "$OUT/er_harsh_k10" --episodes 10 \
  --runs er21_clean er21_bypass er42_clean er42_bypass er43_clean er43_bypass \
  --physics actuation_noise=0.3 odom_noise_position=0.05 odom_noise_yaw=0.1 \
  decision_time_limit=15 --table docs/robot/robot_harsh.md
pimbot robot render "$RUNS/er42_clean" --seed-index 0 --episode 1 \
  --out docs/robot/er42_clean.gif --frame docs/robot/er42_clean_frame.png
pimbot robot render "$RUNS/er21_bypass" --seed-index 0 --episode 0 \
  --out "$OUT/er21_bypass.gif" --frame docs/screenshots/robot_frame_er21_bypass.png
python benchmarks/robot_physics.py --runs-dir "$RUNS" --json docs/robot/robot_physics.json
