"""The confusion experiments' scenarios on a foreign bench, written as bags.

The commands, states of charge and lengths are the project's own (test/test_discrepancy.py:
``REF``, ``SCENARIOS``, ``command``): those are PWM command sequences, not physics, so taking
them keeps the two benches' experiments comparable; every physical response is this package's.
Per case: reference recordings (and a validation recording, for the network path) with the hidden
effect OFF, measured and holdout recordings with it ON, every other effect ON (the realistic
bench); the control has every effect ON everywhere, under the reference's own conditions.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from .draw import draw_bench
from .model import ALL_ON, SWITCHABLE, ForeignBench, simulate
from .record import write_bag

ROOT = Path(__file__).resolve().parents[2]
CASES: tuple[str, ...] = (*SWITCHABLE, "control")
VALIDATION_S = 15.0  #: the network path's early-stopping recording (as test_discrepancy.scenario)


def project_scenarios() -> Any:
    """test/test_discrepancy.py (REF, SCENARIOS, command, HIDDEN, EPOCHS)."""
    if str(ROOT / "test") not in sys.path:
        sys.path.insert(0, str(ROOT / "test"))
    import test_discrepancy

    return test_discrepancy


def case_specs(case: str) -> dict[str, list[tuple[str, float, float]]]:
    """(command kind, state of charge, seconds) per role of ``case``."""
    T = project_scenarios()
    if case not in CASES:
        raise ValueError(f"unknown case {case!r}; cases: {', '.join(CASES)}")
    _, ref_extra, meas, hold = T.SCENARIOS[case]
    return {"reference": [*T.REF, *ref_extra], "validation": [("steps", 1.0, VALIDATION_S)],
            "measured": list(meas), "holdout": list(hold)}


def write_case(case: str, seed: int, directory: Path, bench: ForeignBench | None = None) -> dict[str, list[str]]:
    """Simulate and write every recording of ``case`` on the bench of ``seed``; returns the bag
    paths per role. Recording seeds differ per role, case and bench seed (noise and commands)."""
    T = project_scenarios()
    bench = bench or draw_bench(seed)
    off = {} if case == "control" else {case: False}
    roles = {"reference": (off, 4000), "validation": (off, 4900), "measured": (ALL_ON, 5000),
             "holdout": (ALL_ON, 6000)}
    directory.mkdir(parents=True, exist_ok=True)
    out: dict[str, list[str]] = {}
    for role, specs in case_specs(case).items():
        effects, base = roles[role]
        out[role] = []
        for k, (kind, soc, duration) in enumerate(specs):
            rec_seed = base + 100 * seed + 10 * CASES.index(case) + k
            cmd_t, cmd = T.command(kind, duration, rec_seed)
            run = simulate(bench, cmd_t, cmd, duration, seed=rec_seed, soc0=soc, effects=effects)
            path = directory / f"{role}{k}_{kind}"
            write_bag(run, path)
            out[role].append(str(path))
    return out
