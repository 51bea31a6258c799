"""A bench simulator written apart from bldc_propulsion.sim (issue 30), to judge the discrepancy
workflow on a bench whose structure the package did not write: model (physics and sensors), draw
(randomized benches), scenarios (the confusion experiments' recordings), record (bags)."""
