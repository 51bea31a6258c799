#!/usr/bin/env bash
# The main job end to end on the bundled sample bags: train -> replay -> evaluate -> discrepancy
# (network and physics models).
# Outputs go to demo/ (git-ignored); every step prints what it found.
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
BP=.venv/bin/bldc-propulsion
OUT=demo
mkdir -p "$OUT"
step() { printf '\n== %s\n' "$*"; }

step "1. train the paper's 3-25-1 network (battery voltage, PWM, PWM through 0.25 s) with Levenberg-Marquardt"
$BP train bags/staircase bags/triangle bags/staircase_half bags/triangle_half \
    --validation bags/validation -o $OUT/model.npz --report $OUT/report_train --force 2>$OUT/train.log
tail -n 1 $OUT/train.log | sed 's/^/  last epoch: /'

step "2. replay the chirp recording through the nodes' cores (what the ROS nodes would publish)"
$BP replay bags/chirp -o $OUT/chirp_replay --model $OUT/model.npz --force

step "3. evaluate on recordings the model never saw (chirp: error per command frequency band)"
$BP evaluate --model $OUT/model.npz bags/chirp bags/discharge_a --report $OUT/report_eval

step "4. the paper's question: a model WITHOUT battery voltage, trained on full packs, measured on a half-empty one"
$BP train bags/staircase bags/triangle --validation bags/validation -o $OUT/model_no_voltage.npz \
    --inputs pwm,pwm_filtered --force 2>$OUT/train_no_voltage.log
tail -n 1 $OUT/train_no_voltage.log | sed 's/^/  last epoch: /'
$BP discrepancy --model $OUT/model_no_voltage.npz --measured bags/discharge_a \
    --holdout bags/discharge_b --max-effects 1 -o $OUT/model_found.npz --report $OUT/report_discrepancy --force

step "5. the same question with the bench physics as the model: the nominal motor and propeller, every effect off"
$BP discrepancy --physics --measured bags/staircase bags/validation --holdout bags/discharge_b \
    --max-effects 4 -o $OUT/physics_found.json --report $OUT/report_physics --force 2>$OUT/physics.log
grep -E "^step (4|5)" $OUT/physics.log | sed 's/^/  /'

step "figures: $OUT/report_train/index.html $OUT/report_eval/index.html $OUT/report_discrepancy/index.html $OUT/report_physics/index.html"
