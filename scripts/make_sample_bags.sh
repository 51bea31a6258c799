#!/usr/bin/env bash
# Regenerate bags/ byte for byte from the simulator (seeds and settings are fixed here).
# Bytes depend on the rosbags version that writes the MCAP header: see .venv's `pip show rosbags`.
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
BP=.venv/bin/bldc-propulsion
rm -rf bags && mkdir bags
$BP simulate --profile staircase    --duration 50 --seed 1 -o bags/staircase
$BP simulate --profile triangle     --duration 50 --seed 2 -o bags/triangle
$BP simulate --profile random_steps --duration 30 --seed 3 -o bags/validation
$BP simulate --profile chirp        --duration 60 --seed 4 -o bags/chirp
# the paper's Figs. 3-4: the pack drains at a constant command; measured and holdout halves
$BP simulate --profile constant     --duration 40 --seed 5 --soc 0.55 -o bags/discharge_a
$BP simulate --profile random_steps --duration 30 --seed 6 --soc 0.45 -o bags/discharge_b
du -sh bags/*
