#!/usr/bin/env bash
# The main job end to end on the bundled sample bags: train (network, physics, hybrid) -> replay ->
# evaluate (the three kinds side by side) -> discrepancy (network and physics models).
# Outputs go to demo/ (git-ignored); every step prints what it found; demo/index.html shows
# every report's main figure and headline numbers.
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
BP=.venv/bin/bldc-propulsion
OUT=demo
mkdir -p "$OUT"
# report folders of a demo run older than the report marker: the demo's own outputs, so cleared
# (--force replaces only folders the tool marked as its reports)
for d in "$OUT"/report_*; do
    [ -d "$d" ] && [ ! -f "$d/.bldc-propulsion-report" ] && rm -rf -- "$d"
done
# likewise the replayed recording of a run older than the recording mark (--force replaces only
# recordings whose metadata.yaml carries it: atomic.RECORDING_MARK)
[ -d "$OUT/chirp_replay" ] && ! grep -qs "written_by: bldc-propulsion" "$OUT/chirp_replay/metadata.yaml" \
    && rm -rf -- "$OUT/chirp_replay"
step() { printf '\n== %s\n' "$*"; }

step "0. what the recordings hold (like ros2 bag info)"
$BP info bags/chirp

step "1. train the paper's 3-25-1 network (battery voltage, PWM, PWM through 0.25 s) with Levenberg-Marquardt"
$BP train bags/staircase bags/triangle bags/staircase_half bags/triangle_half \
    --validation bags/validation -o $OUT/model.npz --report $OUT/report_train --force 2>$OUT/train.log

step "1b. the same recordings, two other kinds of model: the bench physics fitted (Kv, CP, effect strengths), and physics + a network on its error"
for kind in physics hybrid; do
    $BP train bags/staircase bags/triangle bags/staircase_half bags/triangle_half \
        --validation bags/validation --kind $kind -o $OUT/model_$kind.npz --force 2>$OUT/train_$kind.log
    { grep -E "^warning" $OUT/train_$kind.log || true; } | sed "s/^/  /"
done

step "2. replay the chirp recording through the nodes' cores (what the ROS nodes would publish)"
$BP replay bags/chirp -o $OUT/chirp_replay --model $OUT/model.npz --force

step "3. evaluate on recordings the model never saw (chirp: error per command frequency band)"
$BP evaluate --model $OUT/model.npz bags/chirp bags/discharge_a --report $OUT/report_eval --force

step "3b. the three kinds side by side on the same unseen recordings (table; one figure per recording)"
$BP evaluate --model $OUT/model.npz --model $OUT/model_physics.npz --model $OUT/model_hybrid.npz \
    bags/chirp bags/discharge_a --report $OUT/report_compare --force | sed -n '/^side by side/,$p'

step "4. the paper's question: a model WITHOUT battery voltage, trained (and validated) on full packs, measured on a half-empty one"
$BP train bags/staircase bags/triangle --validation bags/validation_full -o $OUT/model_no_voltage.npz \
    --inputs pwm,pwm_filtered --force 2>$OUT/train_no_voltage.log
$BP discrepancy --model $OUT/model_no_voltage.npz --measured bags/discharge_a \
    --holdout bags/discharge_b --max-effects 1 -o $OUT/model_found.npz --report $OUT/report_discrepancy --force

step "5. the same question with the bench physics as the model: the nominal motor and propeller, every effect off"
$BP discrepancy --physics --measured bags/staircase bags/validation --holdout bags/discharge_b \
    --max-effects 4 -o $OUT/physics_found.json --report $OUT/report_physics --force 2>$OUT/physics.log
grep -E "^(step (4|5)|warning)" $OUT/physics.log | sed 's/^/  /'

# one page with a thumbnail of each report's main figure and its headline numbers
# (training/report.py reads each report's report.json)
.venv/bin/python -m bldc_propulsion.training.report demo-index "$OUT" --title "bldc_propulsion demo" \
    report_train="1. training the paper's network (RMSE, b, learning curve, Figs. 1, 5-6, 12, 13)" \
    report_eval="3. evaluation on unseen recordings (speed and thrust error, error per command frequency band)" \
    report_compare="3b. network, physics and hybrid side by side on the unseen recordings" \
    report_discrepancy="4. discrepancy: a network without battery voltage on a half-empty pack" \
    report_physics="5. discrepancy: the nominal bench physics as the model" >/dev/null
step "figures: $OUT/index.html (a thumbnail and the headline of report_train, report_eval, report_compare, report_discrepancy, report_physics)"
