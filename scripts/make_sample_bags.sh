#!/usr/bin/env bash
# Regenerate bags/ byte for byte from the simulator (seeds and settings are fixed here).
# Bytes depend on the rosbags version that writes the MCAP header: see .venv's `pip show rosbags`.
#
# The bench: the simulator's nominal one, with an ESC that brakes actively (as BLHeli_S/32
# ESCs do by default: spin_down_asymmetry=0). The packs are at different states of charge, as
# separate bench sessions are: a model can only learn the battery voltage's effect from
# recordings that span it.
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
BP=".venv/bin/bldc-propulsion simulate --effect spin_down_asymmetry=0"
rm -rf bags && mkdir bags
$BP --profile staircase    --duration 30 --seed 1 --soc 1.0  -o bags/staircase
$BP --profile triangle     --duration 30 --seed 2 --soc 0.9  -o bags/triangle
$BP --profile staircase    --duration 30 --seed 3 --soc 0.6  -o bags/staircase_half
$BP --profile triangle     --duration 30 --seed 4 --soc 0.45 -o bags/triangle_half
$BP --profile random_steps --duration 25 --seed 5 --soc 0.75 -o bags/validation
# validation for a model trained on the full packs alone (demo step 4): like its training data
$BP --profile staircase    --duration 30 --seed 9 --soc 0.95 -o bags/validation_full
$BP --profile chirp        --duration 50 --seed 6 --soc 0.85 -o bags/chirp
# the paper's Figs. 3-4: a constant command on a half-empty pack; a holdout at another charge
$BP --profile constant     --duration 35 --seed 7 --soc 0.55 -o bags/discharge_a
$BP --profile random_steps --duration 25 --seed 8 --soc 0.5  -o bags/discharge_b
du -sh bags/* && du -sh bags
