"""The figures the README and docs/results.md quote: each group produced by a script, kept as JSON.

Each group's figures live in ``docs/results/<group>.json`` (the figures, the exact command that
produced them, the date and the commit), written by that command with ``--json``; this script
renders ``docs/results.md`` and the README's demo table from those files, so a figure in the
documentation is always one a script printed (``test/test_results_doc.py`` re-renders both and
recomputes the demo's figures).

    python benchmarks/results.py                 # render docs/results.md and the README regions
    python benchmarks/results.py --check         # exit 1 when either is not what the JSON renders to
    python benchmarks/results.py --update demo   # rerun a group's command (see --list), then render

The demo group is computed here (``scripts/demo.sh``'s commands with ``--json``, a few minutes);
every other group is a benchmark or experiment run with ``--json docs/results/<group>.json``.
A group without its JSON is rendered as "not measured yet" with the command to run.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import math
import os
import platform
import re
import shlex
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bldc_propulsion.atomic import OutputKind, atomic_output, check_output  # noqa: E402
from bldc_propulsion.contract import PWM_STOP  # noqa: E402
from bldc_propulsion.errors import BadInputError  # noqa: E402

RESULTS_DIR = ROOT / "docs" / "results"
RESULTS_MD = ROOT / "docs" / "results.md"
README = ROOT / "README.md"
EFFECTS = ("battery_voltage", "rotor_lag", "input_delay", "esc_deadband", "spin_down_asymmetry", "motor_heating")
NOTHING = "(nothing)"


# --- the record a producer writes ------------------------------------------------------------------
def _is_record(p: Path) -> bool:
    """A JSON file this module wrote (so --json may replace it, and nothing else)."""
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and {"command", "figures"} <= data.keys()


RECORD = OutputKind("figures record", "a figures file (.json) written by a benchmark's --json", (".json",),
                    _is_record)


def check_record_path(path: str | None) -> None:
    """Refuse a --json path before any work (BadInputError, one line): a missing folder, another
    kind of file; an earlier figures record is replaced (that is what rerunning is for). A
    benchmark has no CLI error handling of its own, so the line is printed here (exit 2)."""
    if path is None:
        return
    try:
        check_output(path, RECORD, force=True, option="--json")
    except BadInputError as exc:
        print(f"{Path(sys.argv[0]).name}: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def _finite(x: Any) -> Any:
    """JSON without NaN or infinity (not JSON): None instead, recursively."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def command_line(argv: list[str] | None = None) -> str:
    """The command that is running, as a user retypes it: ``python`` + the script relative to the
    repository root + its options, without ``--json PATH`` (where the figures went)."""
    argv = list(sys.argv if argv is None else argv)
    script = Path(argv[0])
    try:
        script = script.resolve().relative_to(ROOT)
    except ValueError:
        pass
    rest: list[str] = []
    skip = False
    for a in argv[1:]:
        if skip:
            skip = False
        elif a == "--json":
            skip = True
        elif not a.startswith("--json="):
            rest.append(a)
    return shlex.join(["python", str(script), *rest])


def simd_level() -> str | None:
    """The widest vector kernels numpy dispatches to on this CPU (x86: "AVX-512", "AVX2"), or None
    where numpy does not say. Floats fitted on AVX-512 and on AVX2 differ in the last bits, and a
    verdict near its threshold can follow them, so a record keeps it. numpy publishes its runtime
    CPU features only in a private table (numpy.show_runtime prints them): read defensively."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:
        return None
    for name, label in (("AVX512F", "AVX-512"), ("AVX2", "AVX2"), ("SSE42", "SSE4.2"), ("ASIMD", "ASIMD")):
        if features.get(name):
            return label
    return None


def write_record(path: str | os.PathLike[str], figures: dict[str, Any], *, command: str | None = None,
                 seconds: float | None = None) -> None:
    """Write ``figures`` with what produced them (command, date, commit, CPUs and their vector
    kernels, the numerical libraries' versions: both move fitted floats) to ``path``, atomically."""
    # what produced the figures: not the records (earlier runs write them) nor any markdown (renders)
    dirty = bool(_git("status", "--porcelain", "--untracked-files=no", "--", ".",
                      f":(exclude){RESULTS_DIR.relative_to(ROOT)}", ":(exclude)*.md"))
    record = {
        "command": command or command_line(),
        "date": datetime.date.today().isoformat(),
        "commit": _git("rev-parse", "--short", "HEAD") or None,
        "uncommitted_changes": dirty,
        "cpus": os.cpu_count(),
        "simd": simd_level(),
        "libraries": {"python": platform.python_version(),
                      **{k: importlib.metadata.version(k) for k in ("numpy", "scipy")}},
        "seconds": None if seconds is None else round(seconds, 1),
        "figures": _finite(figures),
    }
    with atomic_output(path, force=True, kind=RECORD) as tmp:
        tmp.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n", encoding="utf-8")


def read_record(group: str, directory: Path = RESULTS_DIR) -> dict[str, Any] | None:
    p = directory / f"{group}.json"
    return json.loads(p.read_text(encoding="utf-8")) if p.is_file() else None


# --- the demo group: scripts/demo.sh's commands with --json ------------------------------------------
DEMO_TRAINING = ("bags/staircase", "bags/triangle", "bags/staircase_half", "bags/triangle_half")
DEMO_TESTS = ("bags/chirp", "bags/discharge_a")


def _cli(*args: str) -> dict[str, Any]:
    """One ``bldc-propulsion`` command with ``--json``, as the demo runs it (from the root)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *args, "--json"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise RuntimeError(f"bldc-propulsion {' '.join(args[:1])} exited {proc.returncode}: {last}")
    return json.loads(proc.stdout)


def _scores(evaluation: dict[str, Any]) -> dict[str, Any]:
    """evaluate --json of one model: RMSE per recording (rad/s, % of range), bands, thrust RMSE."""
    out: dict[str, Any] = {}
    for r in evaluation["recordings"]:
        out[Path(r["path"]).name] = {
            "rmse_rad_s": r["rmse_rad_s"], "rmse_percent": r["rmse_percent_of_range"],
            "speed_range_rad_s": r["speed_range_rad_s"], "thrust_rmse_n": r.get("thrust_rmse_n"),
            "bands": [{"low_hz": b["low_hz"], "high_hz": b["high_hz"], "rmse_rad_s": b["rmse_rad_s"],
                       "rmse_percent": b["rmse_percent_of_range"]} for b in r["bands"]],
        }
    return out


def demo_model(kind: str, tmp: Path) -> dict[str, Any]:
    """Steps 1, 1b and 3b for one kind: trained on the four training recordings, scored on the
    unseen chirp and discharge_a (each kind alone: the test recomputes them one by one)."""
    model = tmp / f"model_{kind}.npz"
    t = _cli("train", *DEMO_TRAINING, "--validation", "bags/validation", "--kind", kind, "-o", str(model))
    fig: dict[str, Any] = {"train_rmse_rad_s": t["train_rmse_rad_s"],
                           "validation_rmse_rad_s": t["validation_rmse_rad_s"],
                           "thrust_coefficient": t.get("thrust_coefficient")}
    if kind == "network":
        fig.update(epochs=t["epochs"], best_epoch=t["best_epoch"], best_seed=t.get("best_seed"),
                   restarts=len(t.get("restarts") or []))
    if kind == "physics":
        const, eff = t["constants"], t["effects"]
        fig.update(fit=t.get("fit"), kv_rpm_per_v=const["motor_kv_rpm_per_v"], cp=const["propeller_cp"],
                   throttle_exponent=const.get("esc_throttle_exponent"),
                   dead_time_ms=1000.0 * eff["input_delay"] * _bench().esc_input_delay_s)
    fig["scores"] = _scores(_cli("evaluate", "--model", str(model), *DEMO_TESTS))
    return fig


def demo_bench() -> dict[str, Any]:
    """The simulated bench's true constants, beside the fitted ones."""
    b = _bench()
    return {"kv_rpm_per_v": b.motor_kv_rpm_per_v, "cp": b.propeller_cp,
            "dead_time_ms": 1000.0 * b.esc_input_delay_s, "thrust_coefficient": b.thrust_coefficient}


def demo_models(tmp: Path) -> dict[str, Any]:
    """Steps 1, 1b and 3b: the three kinds, and the bench's truth."""
    return {**{kind: demo_model(kind, tmp) for kind in ("network", "physics", "hybrid")}, "bench": demo_bench()}


def _bench() -> Any:
    from bldc_propulsion.physics.params import BenchParams

    return BenchParams()


def _evidence(data: dict[str, Any]) -> dict[str, Any]:
    """discrepancy --json: per effect its status (added / structural / considered, not added), the
    test that decided it (its reduction and p), the share of the residual it removes on the measured
    data (which only proposes) and on the reference and, where fitted, its value and the holdout."""
    out: dict[str, Any] = {}
    for effect, ev in (data.get("evidence") or {}).items():
        measured = ev.get("measured") or {}
        acc = ev.get("acceptance") or {}
        value = ev.get("fitted_value") or {}
        out[effect] = {
            "verdict": ev.get("verdict"), "p_value": ev.get("p_value"),
            "status": ev.get("status"), "label": ev.get("label"), "decided_by": ev.get("decided_by"),
            "measured_share": measured.get("mse_reduction"),
            "reference_share": (ev.get("reference") or {}).get("mse_reduction"),
            "blocks_improved": measured.get("blocks_improved"), "blocks": measured.get("blocks"),
            "value": value.get("value"), "unit": value.get("unit"), "quantity": value.get("quantity"),
            "holdout_before_rad_s": acc.get("rmse_before_rad_s"), "holdout_after_rad_s": acc.get("rmse_after_rad_s"),
            "holdout_p_value": acc.get("p_value"), "accepted": acc.get("accepted"),
        }
    return out


def demo_discrepancy(tmp: Path) -> dict[str, Any]:
    """Step 4: a model without battery voltage, trained on full packs, asked about a half-empty one."""
    model = tmp / "model_no_voltage.npz"
    _cli("train", "bags/staircase", "bags/triangle", "--validation", "bags/validation_full", "-o", str(model),
         "--inputs", "pwm,pwm_filtered")
    d = _cli("discrepancy", "--model", str(model), "--measured", "bags/discharge_a", "--holdout", "bags/discharge_b",
             "--max-effects", "1")
    return {"named": d["named"], "added": d.get("added", d["named"]),
            "structural": [s["effect"] for s in d.get("structural") or []],
            "holdout_before_rad_s": d["holdout_rmse_before"], "holdout_after_rad_s": d["holdout_rmse_after"],
            "evidence": _evidence(d)}


def demo_physics_discrepancy(tmp: Path) -> dict[str, Any]:
    """Step 5: the nominal bench physics, every effect off, asked what it lacks."""
    d = _cli("discrepancy", "--physics", "--measured", "bags/staircase", "bags/validation", "--holdout",
             "bags/discharge_b", "--max-effects", "4", "-o", str(tmp / "physics_found.json"))
    base = (d.get("calibrated_base") or {}).get("params") or {}
    return {"named": d["named"], "added": d.get("added", d["named"]), "holdout_before_rad_s": d["holdout_rmse_before"],
            "holdout_after_rad_s": d["holdout_rmse_after"],
            "calibrated_kv_rpm_per_v": base.get("motor_kv_rpm_per_v"), "calibrated_cp": base.get("propeller_cp"),
            "calibrated_throttle_exponent": base.get("esc_throttle_exponent"),
            "evidence": _evidence(d)}


#: the demo's parts: each is recomputed on its own by the test (``DEMO_PARTS[name](tmp)``)
DEMO_PARTS: dict[str, Callable[[Path], dict[str, Any]]] = {
    "models": demo_models, "discrepancy": demo_discrepancy, "physics_discrepancy": demo_physics_discrepancy,
}


def produce_demo(path: Path) -> None:
    import time

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        figures = {name: part(Path(d)) for name, part in DEMO_PARTS.items()}
    write_record(path, figures, command="python benchmarks/results.py --update demo",
                 seconds=time.perf_counter() - t0)


# --- formatting --------------------------------------------------------------------------------------
def num(x: float | None, digits: int = 2) -> str:
    return "n/a" if x is None else f"{x:.{digits}f}"


def pct(share: float | None) -> str:
    """A share of a residual (0..1) as the console writes it: a percentage."""
    return "n/a" if share is None else f"{100.0 * share:.1f} %"


def pval(p: float | None) -> str:
    return "n/a" if p is None else f"{p:.2g}"


def spread(values: Iterable[float | None], digits: int = 2, unit: str = "") -> str:
    """median [min, max] of the finite values (what every seeded figure is given as)."""
    v = [float(x) for x in values if x is not None and math.isfinite(float(x))]
    if not v:
        return "n/a"
    u = f" {unit}" if unit else ""
    if len(v) == 1:  # one bench or seed: no spread to give
        return f"{v[0]:.{digits}f}{u}"
    return f"{statistics.median(v):.{digits}f}{u} [{min(v):.{digits}f}, {max(v):.{digits}f}]"


def provenance(rec: dict[str, Any]) -> str:
    commit = rec.get("commit") or "unknown commit"
    extra = " with uncommitted changes" if rec.get("uncommitted_changes") else ""
    took = f", {rec['seconds']:.0f} s" if rec.get("seconds") is not None else ""
    libs = rec.get("libraries") or {}
    on = "".join(f", {k} {libs[k]}" for k in ("numpy", "scipy") if k in libs)
    simd = f", {rec['simd']}" if rec.get("simd") else ""
    return f"measured {rec['date']} at {commit}{extra} ({rec.get('cpus')} CPUs{simd}{on}{took})"


# --- renderers: one per group (a record's figures -> markdown lines) ---------------------------------
KINDS = ("network", "physics", "hybrid")


def _band_label(b: dict[str, Any]) -> str:
    return f"command {b['low_hz']:.1f}-{b['high_hz']:.1f} Hz"


def render_demo(f: dict[str, Any]) -> list[str]:
    m, bench = f["models"], f["models"]["bench"]
    net, phy = m["network"], m["physics"]
    lines = [
        f"Step 1, the paper's 3-25-1 network on the four training recordings ({net['restarts']} LM runs from "
        f"different initial weights, the best on validation kept: seed {net['best_seed']}, {net['epochs']} epochs, "
        f"best at {net['best_epoch']}): RMSE {num(net['train_rmse_rad_s'])} rad/s on the training recordings, "
        f"{num(net['validation_rmse_rad_s'])} rad/s on the validation recording; b = "
        f"{net['thrust_coefficient']:.4g} N s²/rad² (the simulator's: {bench['thrust_coefficient']:.4g}).",
        "",
        f"Step 1b, the bench physics fitted ({phy['fit']}): Kv {phy['kv_rpm_per_v']:.0f} rpm/V, CP "
        f"{phy['cp']:.4f}, dead time {phy['dead_time_ms']:.0f} ms (the bench's {bench['kv_rpm_per_v']:.0f}, "
        f"{bench['cp']:.3f}, {bench['dead_time_ms']:.0f} ms). Training / validation RMSE: "
        + "; ".join(f"{k} {num(m[k]['train_rmse_rad_s'])} / {num(m[k]['validation_rmse_rad_s'])} rad/s"
                    for k in KINDS) + ".",
        "",
        "Step 3b, on recordings no model saw (RMSE in rad/s, in % of the recording's speed range):",
        "",
        "| recording | " + " | ".join(KINDS) + " |",
        "|---|" + "---|" * len(KINDS),
    ]
    for rec in ("chirp", "discharge_a"):
        s = {k: m[k]["scores"][rec] for k in KINDS}
        lines.append(f"| `bags/{rec}` | " + " | ".join(
            f"{num(s[k]['rmse_rad_s'])} ({num(s[k]['rmse_percent'])} %)" for k in KINDS) + " |")
        for i, band in enumerate(s["network"]["bands"]):
            lines.append(f"| {_band_label(band)} | " + " | ".join(
                f"{num(s[k]['bands'][i]['rmse_rad_s'])} ({num(s[k]['bands'][i]['rmse_percent'])} %)"
                for k in KINDS) + " |")
        lines.append(f"| thrust RMSE, `bags/{rec}` (N) | " + " | ".join(
            num(s[k]["thrust_rmse_n"], 3) for k in KINDS) + " |")
    d = f["discrepancy"]
    lines += ["", "Step 4, a model without battery voltage (trained and validated on full packs) on a half-empty "
              f"pack: added {_added(d)}; "
              f"holdout RMSE {num(d['holdout_before_rad_s'])} → {num(d['holdout_after_rad_s'])} rad/s. "
              "Every candidate (share of the residual removed on held-out blocks):", ""]
    lines += _evidence_table(d["evidence"], reference=True)
    p = f["physics_discrepancy"]
    lines += ["", "Step 5, the nominal bench physics with every effect off (Kv, CP and the throttle exponent "
              f"calibrated to {num(p['calibrated_kv_rpm_per_v'], 0)} rpm/V, {num(p['calibrated_cp'], 4)} and "
              f"{num(p['calibrated_throttle_exponent'])}): added {_added(p)}; holdout RMSE "
              f"{num(p['holdout_before_rad_s'])} → {num(p['holdout_after_rad_s'])} rad/s.", ""]
    lines += _evidence_table(p["evidence"], reference=False)
    return lines


def _added(x: dict[str, Any]) -> str:
    """The effects added, each with what it was added as (new in the measured data or structural)."""
    added = x.get("added", x["named"])
    return ", ".join(f"{e} ({'new' if e in x['named'] else 'structural'})" for e in added) or "nothing"


def _evidence_table(evidence: dict[str, Any], reference: bool) -> list[str]:
    """One row per candidate in the workflow's vocabulary: its status and the test that decided it."""
    head = ("| effect | status | deciding test: reduction, p | measured share (proposes) | "
            + ("reference share | " if reference else "") + "fitted | holdout RMSE |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for effect, e in evidence.items():
        fitted = (f"{e['quantity']} {e['value']:.4g} {e['unit']}" if e.get("value") is not None else "")
        hold = (f"{num(e['holdout_before_rad_s'])} → {num(e['holdout_after_rad_s'])} rad/s"
                if e.get("holdout_before_rad_s") is not None else "")
        dec = e.get("decided_by") or {}
        decided = (f"{dec['test']}: {num(dec['reduction_pct'], 1)} %, p {pval(dec['p_value'])}" if dec else "")
        lines.append(f"| {effect} | {e.get('label') or e['verdict']} | {decided} | {pct(e['measured_share'])} | "
                     + (f"{pct(e['reference_share'])} | " if reference else "")
                     + f"{fitted} | {hold} |")
    return lines


def render_demo_readme(f: dict[str, Any]) -> list[str]:
    """The README's one table: the demo's headline numbers."""
    m = f["models"]
    net, phy, bench = m["network"], m["physics"], m["bench"]
    chirp = {k: m[k]["scores"]["chirp"] for k in KINDS}
    dis = {k: m[k]["scores"]["discharge_a"] for k in KINDS}
    fast = {k: chirp[k]["bands"][-1] for k in KINDS}
    d, p = f["discrepancy"], f["physics_discrepancy"]
    # step 4's leading candidate (the most of the measured residual): its verdict and both shares
    lead, ev = max(d["evidence"].items(), key=lambda kv: kv[1].get("measured_share") or -math.inf)

    def added(x: dict[str, Any]) -> str:
        return ", ".join(f"`{e}`" + ("" if e in x["named"] else " (structural)")
                         for e in x.get("added", x["named"])) or "nothing"

    rows = [
        ("1. network (3-25-1): RMSE training / validation",
         f"{num(net['train_rmse_rad_s'])} / {num(net['validation_rmse_rad_s'])} rad/s"),
        ("1. b fitted on the load cell (true)",
         f"{net['thrust_coefficient']:.4g} N s²/rad² ({bench['thrust_coefficient']:.4g})"),
        ("1b. physics fitted: Kv, CP, dead time (true)",
         f"{phy['kv_rpm_per_v']:.0f} rpm/V, {phy['cp']:.4f}, {phy['dead_time_ms']:.0f} ms "
         f"({bench['kv_rpm_per_v']:.0f}, {bench['cp']:.3f}, {bench['dead_time_ms']:.0f})"),
        ("3b. unseen chirp: network / physics / hybrid",
         " / ".join(num(chirp[k]["rmse_percent"]) for k in KINDS) + " % of the range ("
         + " / ".join(num(chirp[k]["rmse_rad_s"]) for k in KINDS) + " rad/s)"),
        (f"3b. the chirp's {fast['network']['low_hz']:.0f}-{fast['network']['high_hz']:.0f} Hz part",
         " / ".join(num(fast[k]["rmse_percent"]) for k in KINDS) + " %"),
        ("3b. unseen half-empty pack (`discharge_a`)", " / ".join(num(dis[k]["rmse_percent"]) for k in KINDS) + " %"),
        ("3b. thrust RMSE on the chirp", " / ".join(num(chirp[k]["thrust_rmse_n"], 3) for k in KINDS) + " N"),
        ("4. no voltage, half-empty pack",
         f"`{lead}` {ev.get('status') or ev['verdict']}: {pct(ev.get('measured_share'))} of the residual "
         f"({pct(ev.get('reference_share'))} on its training data)"),
        ("4. added; holdout RMSE", f"{added(d)}; {num(d['holdout_before_rad_s'])} → "
                                   f"{num(d['holdout_after_rad_s'])} rad/s"),
        ("5. nominal physics, every effect off: added", added(p)),
        ("5. holdout RMSE", f"{num(p['holdout_before_rad_s'])} → {num(p['holdout_after_rad_s'])} rad/s"),
    ]
    return ["| demo step | result |", "|---|---|", *(f"| {a} | {b} |" for a, b in rows)]


def render_confusion(f: dict[str, Any], key: str = "effect") -> list[str]:
    """A confusion table (true effect x first named) from a run list, and the holdout reduction."""
    runs = f["runs"]
    cases = [e for e in [*EFFECTS, "control"] if any(r[key] == e for r in runs)]
    cols = [*EFFECTS, NOTHING]
    short = {"battery_voltage": "battery", "spin_down_asymmetry": "spin-down", "motor_heating": "heating",
             "esc_deadband": "deadband", "input_delay": "delay", "rotor_lag": "lag", NOTHING: "nothing"}
    lines = ["| true \\ first named | " + " | ".join(short[c] for c in cols) + " | right |",
             "|---|" + "---|" * (len(cols) + 1)]
    for case in cases:
        mine = [r for r in runs if r[key] == case]
        want = NOTHING if case == "control" else case
        lines.append(f"| {case} | " + " | ".join(str(sum(r['first'] == c for r in mine)) for c in cols)
                     + f" | {sum(r['first'] == want for r in mine)}/{len(mine)} |")
    right = sum(r["first"] == (NOTHING if r[key] == "control" else r[key]) for r in runs)
    false = sum(len(r["named"]) for r in runs if r[key] == "control")
    seeds = sorted({r["seed"] for r in runs})
    controls = (f"false names on the controls: {false}" if any(r[key] == "control" for r in runs)
                else "no control runs")
    lines += ["", f"Named right first: **{right}/{len(runs)}**; {controls}; "
              + (f"seeds {seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else f"seed {seeds[0]}")
              + ". Holdout RMSE reduction, median [min, max] over seeds:", ""]
    what = "strength" if any("strength" in r for r in runs) else "value"
    for case in cases:
        red = [100.0 * (1.0 - r["after"] / r["before"]) for r in runs
               if r[key] == case and r.get("before") and r.get("after") is not None]
        # the strength against the truth (own benches), or the physical value (a foreign bench's)
        ratio = [x for r in runs if r[key] == case and math.isfinite(x := _ratio(r))]
        within = f", {sum(abs(x - 1.0) <= 0.3 for x in ratio)}/{len(ratio)} within 30 %" if ratio else ""
        lines.append(f"- {case}: {spread(red, 1, '%')}"
                     + (f"; fitted {what} / truth {spread(ratio)}{within}" if ratio else ""))
    extra = [f"{r[key]} seed {r['seed']}: {', '.join(n for n in r['named'][1:] if n != r[key])}" for r in runs
             if r[key] != "control" and any(n != r[key] for n in r["named"][1:])]
    lines += ["", f"Names after the first that are not the hidden effect: {len(extra)} of "
              f"{sum(r[key] != 'control' for r in runs)} effect runs" + (f" ({'; '.join(extra)})." if extra else ".")]
    return lines


def _ratio(run: dict[str, Any]) -> float:
    """A run's fitted strength over its truth (own benches), or its physical value over the
    bench's (foreign; a start level as its distance from PWM_STOP); NaN when either is missing."""
    v, truth = run.get("strength", run.get("fitted")), run.get("truth")
    if not isinstance(v, int | float) or not isinstance(truth, int | float) or not truth:
        return math.nan
    if run.get("unit") == "PWM level":
        v, truth = v - PWM_STOP, truth - PWM_STOP
    return float(v) / float(truth)


#: A foreign run's hidden effect that moves the measured speed by less than this (RMS, rad/s: a
#: hundredth of a tachometer's count at these benches' speeds) is no effect the data hold: a start
#: level below the level where the motor breaks away, say. Its measured recordings are the
#: reference's own, so it is judged as a control (right: naming nothing), and said so.
INVISIBLE_RAD_S = 0.01


def judged_case(run: dict[str, Any]) -> str:
    """What a foreign run is judged as: its hidden effect, or "control" when the effect does not
    move the measured speed at all (INVISIBLE_RAD_S; runs without the figure keep their case)."""
    size = run.get("effect_rad_s")
    if run["case"] != "control" and isinstance(size, int | float) and size < INVISIBLE_RAD_S:
        return "control"
    return str(run["case"])


def render_foreign(f: dict[str, Any], path: str) -> list[str]:
    """bench_foreign.py's runs of one path (a run of both paths holds the other's too)."""
    runs = [{**r, "judged": judged_case(r)} for r in f["runs"] if r["path"] == path]
    lines = render_confusion({"runs": runs}, key="judged")
    if invisible := [r for r in runs if r["judged"] != r["case"]]:
        lines += ["", "Judged as controls, since the hidden effect does not move the measured speed (below "
                  f"{INVISIBLE_RAD_S} rad/s RMS, the bench's physics with it on against off): "
                  + "; ".join(f"{r['case']} seed {r['seed']} ({r['effect_rad_s']:.2g} rad/s, named "
                              f"{', '.join(r['named']) or 'nothing'})" for r in invisible) + "."]
    missed = [r for r in runs if r["judged"] != "control" and r["first"] != r["case"] and "effect_rad_s" in r]
    if missed:  # bench_foreign: what the missed effect does to the measured speed at all, beside the residual
        lines += ["", "Where the hidden effect was not named first, what it does to the measured speed (RMS, the "
                  "bench's physics with it on against off) beside the holdout residual before: "
                  + "; ".join(f"{r['case']} seed {r['seed']} {r['effect_rad_s']:.2f} vs {r['before']:.1f} rad/s"
                              for r in missed) + "."]
    if aside := [r for r in runs if "per_k" in r]:  # bench_foreign.IDENTIFIED: why heating's %/K is not judged
        lines += ["", "Heating is judged on the share of the full-drive speed lost once the winding is warm (what "
                  "the speed identifies). Not judged, as the CONFIG's winding resistance and thermal capacity set "
                  "them: " + "; ".join(f"seed {r['seed']} {r['per_k']:.3g} vs {r['truth_per_k']:.3g} %/K, "
                                       f"time constant {r['tau_s']:.0f} vs {r['truth_tau_s']:.0f} s" for r in aside)
                  + "."]
    return lines


def render_accuracy(f: dict[str, Any]) -> list[str]:
    cols = f["columns"]
    lines = ["| kind | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    order = sorted(f["results"], key=lambda k: (KINDS.index(k) if k in KINDS else len(KINDS), k))  # floor last
    for kind in order:
        rows = f["results"][kind]
        lines.append(f"| {kind} | " + " | ".join(spread(r.get(c) for _, r in rows) for c in cols) + " |")
    benches = [label for label, _ in next(iter(f["results"].values()))]
    lines += ["", "RMSE in % of each recording's speed range" + (", median [min, max] over the benches" if
              len(benches) > 1 else "") + f"; bench{'es' if len(benches) > 1 else ''}: {', '.join(benches)}. "
              "The floor is the decoded speed's own error against the simulator's truth."]
    if rows := f["results"].get("hybrid"):  # issue 13's goal, on every bench
        within = sum(r["chirp"] < 1.5 and r["low charge"] < 1.5 for _, r in rows)
        lines += ["", f"Goal, hybrid chirp and low charge < 1.5 % on every bench: {within} of {len(rows)} benches "
                  + ("(met)." if within == len(rows) else "(**not met**).")]
    return lines


def render_real(f: dict[str, Any]) -> list[str]:
    """The thrust law per log and, when the splits were run, every kind on each held-out part."""
    lines: list[str] = []
    if law := f.get("thrust_law"):
        lines += ["| log | rows | b, N s²/rad² | CT | b below / above the median speed |", "|---|---|---|---|---|"]
        lines += [f"| `{r['log']}` | {r['rows']} | {r['b']:.3g} | {r['ct']:.3f} | "
                  f"{r['b_low']:.2g} / {r['b_high']:.2g} |" for r in law]
        med = statistics.median(r["b"] for r in law)
        lines += ["", f"b median {med:.3g} N s²/rad², {100 * (min(r['b'] for r in law) / med - 1):+.1f} % to "
                  f"{100 * (max(r['b'] for r in law) / med - 1):+.1f} % of it across the six logs."]
    if splits := f.get("splits"):
        lines += [""] if lines else []
        lines += [f"`{f['log']}` cut in {1 + max(r['split'] for r in splits)} parts in time; each part is the test "
                  "of models trained and validated on the others. RMSE in % of the log's speed range "
                  f"({f['log_range_rad_s']:.0f} rad/s):", "",
                  f"| test part | kind | RMSE | Kv, rpm/V (rated {f['rated_kv']:.0f}) | "
                  "b / direct fit: training, test part | thrust RMSE, % of the log's thrust range |",
                  "|---|---|---|---|---|---|"]
        for r in splits:
            if r.get("refused"):  # train's one line: what it refused, up to the first ";"
                why = r["refused"].split("error: ", 1)[-1].split(";", 1)[0]
                lines.append(f"| {r['split']} | {r['kind']} | refused: {why} | | | |")
                continue
            ratio = r["b"] / r["b_direct"] if r.get("b") and r.get("b_direct") else None
            trained = r["b"] / r["b_direct_training"] if r.get("b") and r.get("b_direct_training") else None
            thrust = (100.0 * r["thrust_rmse_n"] / f["log_thrust_range_n"]
                      if r.get("thrust_rmse_n") is not None and f.get("log_thrust_range_n") else None)
            lines.append(f"| {r['split']} | {r['kind']} | {num(r.get('percent'))} % | {num(r.get('kv'), 0)} | "
                         f"{num(trained, 3)}, {num(ratio, 3)} | {num(thrust)} % |")
        lines += _fit_flag_lines(splits)
        if spans := f.get("speed_contradicted_s"):
            lines += ["", "`import-csv` finds the log's speed column contradicted by its thrust at "
                      + ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in spans)
                      + " (the log's time; the probe reads far below what the load cell says): "
                      + ("every piece is imported with the speed left out there (`--drop-contradicted`, where the "
                         "piece's own import finds it too): the models are neither trained nor scored on it."
                         if f.get("speed_dropped") else "the models are scored and trained on those rows as read.")]
    if revisited := f.get("revisited"):
        lines += ["", "The same command on the staircase's way up and on its way down (settled medians of the log, "
                  "no model):", "",
                  "| command | way up: part, speed, current, voltage | way down: part, speed, current, voltage | "
                  "speed down / up | shaft / supply power, up → down |", "|---|---|---|---|---|"]
        for r in revisited:
            u, w = r["up"], r["down"]
            eff = (f"{u['efficiency']:.3f} → {w['efficiency']:.3f}" if "efficiency" in u and "efficiency" in w
                   else "n/a")
            lines.append(f"| {r['us']:.0f} µs | {u['part']}, {u['speed_rad_s']:.0f} rad/s, {u['current_a']:.1f} A, "
                         f"{u['voltage_v']:.2f} V | {w['part']}, {w['speed_rad_s']:.0f} rad/s, {w['current_a']:.1f} A, "
                         f"{w['voltage_v']:.2f} V | {w['speed_rad_s'] / u['speed_rad_s']:.3f} | {eff} |")
        slower = [100.0 * (1.0 - r["down"]["speed_rad_s"] / r["up"]["speed_rad_s"]) for r in revisited]
        less = [100.0 * (1.0 - r["down"]["current_a"] / r["up"]["current_a"]) for r in revisited]
        lost = [100.0 * (r["up"]["efficiency"] - r["down"]["efficiency"]) for r in revisited
                if "efficiency" in r["up"] and "efficiency" in r["down"]]
        down = sorted({r["down"]["part"] for r in revisited})
        lines += ["", f"At the same command and supply voltage the way down runs {min(slower):.1f}-{max(slower):.1f} % "
                  f"slower on {min(less):.1f}-{max(less):.1f} % less current"
                  + (f", and turns {min(lost):.1f} to {max(lost):.1f} points less of the supply's power into shaft "
                     "power (the log's torque)" if lost else "")
                  + ": a motor and ESC still warm from full drive would, though the log cannot say which part is "
                  f"warm. Every hold of the way down lies in part {', '.join(map(str, down))}: the models "
                  "tested there were trained on parts that show only the way up."]
    if (health := f.get("health")) is not None:
        lines += ["", f"The health monitor over the whole log with each split's model. {f['health_context']}", ""]
        alarmed = sum(1 for h in health if h["events"])
        lines += [f"Runs with an alarm: {alarmed} of {len(health)}.", ""] if health else []
        lines += [f"- split {h['split']}, {h['kind']}: {'; '.join(map(str, h['events'])) or 'no change'}"
                  + "".join(f"; minor, no alarm: {m}" for m in h.get("minor", []))
                  + f" ({h['monitored_s']:.0f} of {h['duration_s']:.0f} s monitored)" for h in health]
        if not health:
            lines.append("- no physics or hybrid model was trained (each refused above), so nothing was monitored")
    return lines


#: a training warning of a constant the fit left at a bound (physics.fit.FitFlag.text via train)
_NUMBER = r"-?\d+(?:\.\d*)?(?:e[-+]?\d+)?"
_AT_BOUND = re.compile(rf"^training fit: (?P<quantity>.+?) fitted (?P<value>{_NUMBER}) vs .*"
                       rf"\(at a bound of its range (?P<low>{_NUMBER})-(?P<high>{_NUMBER})\)$")
#: train's warning that a hybrid holds no correction (its network did not beat the physics)
_HYBRID_IS_PHYSICS = "the hybrid's correction is 0"


def _fit_flag_lines(splits: list[dict[str, Any]]) -> list[str]:
    """What each split's training could not pin down, from train's warnings in the record: the
    constants fitted at a bound of their range (no figure of the log; a model holding them is
    only as good as its held-out RMSE says), and the hybrids that are the physics alone."""
    lines: list[str] = []
    for split in sorted({r["split"] for r in splits}):
        flags: dict[str, str] = {}
        for w in (w for r in splits if r["split"] == split for w in r.get("warnings", [])):
            if m := _AT_BOUND.match(w):
                value = float(m["value"])
                low = abs(value - float(m["low"])) <= abs(value - float(m["high"]))
                flags.setdefault(m["quantity"], f"{m['quantity']} at the {'low' if low else 'high'} end of "
                                                f"{m['low']}-{m['high']}")
        if flags:
            lines.append(f"- split {split}: " + "; ".join(flags.values()))
    if lines:
        lines = ["", "Constants the training data could not pin down (fitted at a bound of their range; train "
                 "warns, and no figure here rests on them; an effect's strength at 0 is the fit turning it off):", "",
                 *lines]
    alone = sorted({r["split"] for r in splits if r["kind"] == "hybrid"
                    and any(_HYBRID_IS_PHYSICS in w for w in r.get("warnings", []))})
    if alone:
        lines += ["", f"The hybrid of split{'s' if len(alone) > 1 else ''} {', '.join(map(str, alone))} is the "
                  "physics alone: its network did not improve on the physics on the validation recordings."]
    return lines


def render_flight(f: dict[str, Any]) -> list[str]:
    """bench_flight: each bench's scored pieces per kind, and the spread against issue 29's goals."""
    kinds = sorted(f["summary"], key=lambda k: KINDS.index(k) if k in KINDS else len(KINDS))
    tests = [x["soc"] for x in f["flights"] if x["role"] == "test"]
    lines = ["| bench | " + " | ".join(kinds) + " |", "|---|" + "---|" * len(kinds)]
    for r in f["benches"]:
        lines.append(f"| {r['seed']} | " + " | ".join(" / ".join(f"{v:.2f}" for v in r[k]["percent"]) + " %"
                                                 for k in kinds) + " |")
    charges = ", ".join(f"{100 * x:.0f}" for x in tests)
    lines += ["", f"RMSE in % of each scored piece's speed range, the pieces at {charges} % charge in that order; "
              f"{f['flight_s']:g} s each. Over every scored piece:", ""]
    for k in kinds:
        s = f["summary"][k]
        goal = ("" if s["goal"] is None else
                f"; goal at most {s['goal']:g} %: {s['within']} of {s['scored']} pieces"
                + (" (met)" if s["within"] == s["scored"] else " (**not met**)"))
        lines.append(f"- {k}: median {s['median']:.2f} % [{s['min']:.2f}, {s['max']:.2f}]{goal}")
    return lines


def render_splits(f: dict[str, Any]) -> list[str]:
    """A real log's splits, levels and health lines: ``render_real`` without the thrust law (its group)."""
    return render_real({k: v for k, v in f.items() if k != "thrust_law"})


def render_speed(f: dict[str, Any]) -> list[str]:
    """A benchmark's figures as printed: what, value, unit, goal (CPU time of one process)."""
    lines = ["| what | measured | goal |", "|---|---|---|"]
    for r in f["figures"]:
        lines.append(f"| {r['what']} | {r['value']:.2f} {r['unit']} | {r['goal']} |")
    return lines


def _share(k: int, n: int) -> str:
    return f"{k}/{n} ({100.0 * k / n:.0f} %)" if n else "n/a"


def _fault_size(size: float | None, unit: str) -> str:
    """A fault's size as the issue writes it: 0.1 (fraction of CT and CP), 2x, 30 K."""
    if size is None:
        return "n/a"
    return {"factor": f"{size:g}x", "K": f"{size:g} K"}.get(unit, f"{size:g}")


def _size_error(err: float | None, unit: str, signed: bool = True) -> str:
    if err is None:
        return "n/a"
    digits = {"factor": 2, "K": 1}.get(unit, 3)
    text = f"{err:+.{digits}f}" if signed else f"{err:.{digits}f}"
    return text + {"factor": "x", "K": " K"}.get(unit, "")


def _health_goals(f: dict[str, Any]) -> list[str]:
    """The issue's goals against the figures, stated plainly: met, NOT met (by how much), or not
    shown (too few healthy hours to tell)."""
    goal, within, need_h = f["goal_share"], f["detect_within_s"], f["goal_healthy_hours"]
    h = f["healthy"]
    short = []
    for name in f["fault_order"]:
        x = f["faults"][name]
        k, n = x["counts"]["detected_and_named_right"], x["runs"]
        if not n or k / n < goal:
            gap = round(100.0 * (goal - (k / n if n else 0.0)))
            short.append(f"{name} {_share(k, n)}, {gap} point{'' if gap == 1 else 's'} short")
    alarms, hours = h["false_alarms"], h["hours_monitored"]
    if alarms:
        fa = (f"{alarms} false alarm{'s' if alarms != 1 else ''} in {hours:.2f} h of healthy flight "
              f"({num(h['false_alarms_per_hour'])} per hour, about {10.0 * h['false_alarms_per_hour']:.0f} in "
              f"{need_h:g} h) against none in {need_h:g} h")
    else:
        fa = None
    verdict = "NOT met" if short or fa else (
        "met on these benches (whether they hold elsewhere: the other sets above)" if hours >= need_h else "not shown")
    lines = [f"**The issue's goals (at least {100 * goal:.0f} % of each fault detected within {within:g} s and named "
             f"right first; no false alarm in {need_h:g} h of healthy flight) are {verdict}.**"]
    if short:
        lines.append(f"- Detected within {within:g} s and named right first, against {100 * goal:.0f} %: "
                     + "; ".join(short) + ".")
    if fa:
        lines.append(f"- False alarms: {fa}.")
    elif hours < need_h:
        lines.append(f"- False alarms: none in {hours:.2f} h, too few hours to show none in {need_h:g} h.")
    else:
        lines.append(f"- False alarms: none in {hours:.2f} h of healthy flight (met).")
    return lines


def _health_renamed(f: dict[str, Any]) -> str:
    """How many runs were named again while sized (a record without the count: nothing)."""
    counts = {name: f["faults"][name]["counts"].get("renamed") for name in f["fault_order"]}
    if any(v is None for v in counts.values()):
        return ""
    total = sum(int(v) for v in counts.values() if v is not None)
    which = ", ".join(f"{name} {v}" for name, v in counts.items() if v)
    return (" A change named again while it was sized (its status showed another name first) is not named right "
            f"first: {total} such run{'' if total == 1 else 's'}" + (f" ({which})" if which else "") + ".")


def _health_could_show(f: dict[str, Any]) -> list[str]:
    """The goal's figure over the runs whose rotor turned long enough after the onset for the
    fault to show (a record without it: nothing)."""
    if "turning_share" not in f or f.get("profile", "random_steps") != "random_steps":
        return []
    within = f["detect_within_s"]
    need = f["turning_share"] * within
    parts = [f"{name} {_share(f['faults'][name]['counts']['could_show_detected_and_named_right'], c)}"
             for name in f["fault_order"] if (c := f["faults"][name]["counts"]["could_show"]) is not None]
    return [f"A fault shows only while the rotor turns, and random steps hold the motor stopped or below its "
            f"start level for seconds, which a multirotor in flight never does. Over the runs whose simulated "
            f"rotor turned (above {100 * f['min_speed_fraction']:.0f} % of the flight's fastest) for at "
            f"least {need:g} s of the {within:g} s after the onset, detected within {within:g} s and named right "
            "first: " + "; ".join(parts) + ".", ""]


def _health_speed_tested(f: dict[str, Any]) -> list[str]:
    """The goal's figure over the runs whose speed the monitor tested after the onset, and the
    healthy hours it tested it (a record without it: nothing)."""
    if "hours_speed_tested" not in f["healthy"]:
        return []
    within = f["detect_within_s"]
    need = f["turning_share"] * within
    parts = [f"{name} {_share(c['speed_tested_detected_and_named_right'], c['speed_tested'])} "
             f"(the speed tested in {c['speed_tested']} of {f['faults'][name]['runs']} runs)"
             for name in f["fault_order"] if (c := f["faults"][name]["counts"])]
    h = f["healthy"]
    return ["The monitor tests the speed only once its reference holds enough steady seconds at speeds whose model "
            "error it has learned (`HealthMonitor.testing`; its status says so while it does not): a flight that "
            "never holds a speed can leave it untested for a minute, the voltage alone watching. Over the runs whose "
            f"speed tests ran for at least {need:g} s of the {within:g} s after the onset (they run with the rotor "
            f"at rest too, where no block is steady), detected within "
            f"{within:g} s and named right first: " + "; ".join(parts) + ". The healthy flights' speed was tested "
            f"{h['hours_speed_tested']:.2f} h of the {h['hours_monitored']:.2f} h monitored.", ""]


#: How a health record's flights are described, by their command profile (sim/profiles.py).
PROFILE_TEXT = {
    "random_steps": "random steps (levels over the whole range held 0.5-5 s, the motor stopped at times)",
    "flight": "one multirotor motor (`--profile flight`: never stopped, a hover level with manoeuvres and "
              "punch-outs, moved every frame by the attitude loop's dither)",
}


def render_health(f: dict[str, Any]) -> list[str]:
    """bench_health.py: per fault what the monitor said first after the onset, the healthy
    flights' false alarms, the spread per bench, and the issue's goals against them."""
    within = f["detect_within_s"]
    benches, tuned = f["benches"], f["tuning_benches"]
    lines = [*_health_goals(f), "",
             f"| fault, size | runs | detected ≤ {within:g} s | named right first | both (the goal) | "
             f"named right ≤ {within:g} s | named wrong | unnamed | missed | delay median / max | "
             "size error median / max abs |", "|---|" + "---|" * 10]
    for name in f["fault_order"]:
        x = f["faults"][name]
        c, n, unit = x["counts"], x["runs"], f["units"][name]
        lines.append(
            f"| {name} {_fault_size(f['sizes'][name], unit)} | {n} | {_share(c['detected_within_5s'], n)} | "
            f"{_share(c['named_right_first'], n)} | **{_share(c['detected_and_named_right'], n)}** | "
            f"{_share(c['named_right_within_5s'], n)} | {_share(c['named_wrong'], n)} | {_share(c['unnamed'], n)} | "
            f"{_share(c['missed'], n)} | {num(x['delay_median_s'])} / {num(x['delay_max_s'])} s | "
            f"{_size_error(x['size_error_median'], unit)} / {_size_error(x['size_error_max_abs'], unit, False)} |")
    h = f["healthy"]
    before = sum(x["false_alarms_before_onset"] for x in f["faults"].values())
    names: dict[str, int] = {}
    for a in h["alarms"]:
        names[a["name"]] = names.get(a["name"], 0) + 1
    flight = PROFILE_TEXT.get(f.get("profile", "random_steps"), f"the `{f.get('profile')}` profile")
    lines += ["", f"Each run is one {f['flight_s']:.0f} s flight of {flight} with the fault injected at a random "
              f"onset ({f['onset_range_s'][0]:.0f}-{f['onset_range_s'][1]:.0f} s); the first change the monitor "
              f"reports after the onset is named right, wrong, unnamed, or there is none (missed). The name may come "
              f"up to {f['name_within_s']:g} s after the onset; \"named right ≤ {within:g} s\" also asks the name "
              f"within {within:g} s. Delays: onset to detection, over the runs detected in time; size error: "
              "reported minus injected size (propeller_damage: the fraction of CT and CP lost), over the runs "
              "named right." + _health_renamed(f), "", *_health_could_show(f), *_health_speed_tested(f),
              f"Healthy flights: {h['flights']} of {f['healthy_flight_s']:.0f} s, {h['hours_monitored']:.2f} h "
              f"monitored (after each flight's first full window), **{h['false_alarms']} false alarm"
              f"{'s' if h['false_alarms'] != 1 else ''}** ({num(h['false_alarms_per_hour'])} per hour)"
              + (": " + ", ".join(f"{k} {v}" for k, v in sorted(names.items())) if names else "")
              + f". False alarms before the onset in the fault flights (not counted here): {before}.", "",
              f"Benches: seeds {', '.join(map(str, benches))} (`sim.random_bench.draw_bench`), each with its own "
              "physics model fitted on 90 s of random steps on the healthy bench. The monitor's settings "
              "(`core.health.HealthConfig`) "
              f"were tuned on bench seed{'s' if len(tuned) != 1 else ''} {', '.join(map(str, tuned))} only (flight "
              f"seeds {', '.join(map(str, f['tuning_flight_seeds']))}), none of the benches above.", "",
              "Per bench, detected within 5 s and named right first; false alarms on its healthy flights:", "",
              "| bench | " + " | ".join(f["fault_order"]) + " | healthy h | false alarms |",
              "|---|" + "---|" * (len(f["fault_order"]) + 2)]
    for b in map(str, benches):
        cells = [(lambda p: _share(p["detected_and_named_right"], p["runs"]) if p else "n/a")(
            f["faults"][name]["per_bench"].get(b)) for name in f["fault_order"]]
        hb = h["per_bench"].get(b, {"hours_monitored": 0.0, "false_alarms": 0})
        lines.append(f"| {b} | " + " | ".join(cells) + f" | {hb['hours_monitored']:.2f} | {hb['false_alarms']} |")
    return lines


def render_band(f: dict[str, Any]) -> list[str]:
    """bench_band.py: per kind the share of held-out measured speeds inside the one-sigma band."""
    lo, hi = f["goal_percent"]
    lines = [f"Benches {', '.join(f['benches'])}; goal {lo:.0f}-{hi:.0f} % pooled, every kind.", "",
             "| kind | pooled | per bench: median [min, max] | per recording kind | mean sigma "
             "| on its own validation | goal |",
             "|---|---|---|---|---|---|---|"]
    for kind, k in f["kinds"].items():
        per = list(k["per_bench_percent"].values())
        tests = ", ".join(f"{name} {v:.1f} %" for name, v in k.get("per_test_percent", {}).items())
        lines.append(f"| {kind} | {k['pooled_percent']:.1f} % | {statistics.median(per):.1f} "
                     f"[{min(per):.1f}, {max(per):.1f}] % | {tests or '-'} | {k['mean_sigma_rad_s']:.2f} rad/s | "
                     f"{k['validation_percent']:.1f} % | {'met' if k['goal_met'] else 'not met'} |")
    return lines


def _median_worst(xs: list[float | None]) -> str:
    """median / worst of a list; None (never recovered) counts as the worst."""
    if not xs:
        return "-"
    vals = [math.inf if x is None else float(x) for x in xs]
    return f"{statistics.median(vals):.2f} / {max(vals):.2f}"


def _median(xs: list[float], decimals: int = 2) -> str:
    """The median of a list; "-" for none."""
    return f"{statistics.median(xs):.{decimals}f}" if xs else "-"


def pack_change(rows: list[dict[str, Any]]) -> str:
    """The adapted pack resistance at the end over the twin's (median over the runs where both are
    known), as a phrase to append; empty for a record from before the pack was adapted."""
    pairs = [(r["final"]["pack_resistance"], r["final_twin"]["pack_resistance"]) for r in rows if "final_twin" in r]
    ratios = [a / b for a, b in pairs if math.isfinite(a / b)]
    return f", pack x{statistics.median(ratios):.2f} the twin's ({len(ratios)} known)" if ratios else ""


def render_adaptation(f: dict[str, Any]) -> list[str]:
    """bench_adaptation.py: per fault the RMSE after the change over the same flight's without it
    (its twin) and over the seconds before the onset (adapted and offline), the recovery times, the
    thrust's RMSE after the change, the adapted values; healthy flights: adapted over offline RMSE."""
    goal, goal_healthy = 1.2, 1.05
    lines = [f"Benches {', '.join(map(str, f['benches']))} (`sim.random_bench`), never tuned on (the adapter's "
             f"settings, `core.adaptation.AdaptationConfig`, were tuned on benches "
             f"{', '.join(map(str, f['tuning_benches']))}). The goals: after a change, RMSE back within {goal}x "
             f"of its pre-change level within 10 s; on healthy flights, adapted RMSE at most {goal_healthy}x "
             "the offline model's. The pre-change level is taken two ways: the same flight simulated without "
             "the change (its twin: same seed, state of charge and command), through the same estimator, over "
             "the same seconds; and the 20 s before the onset. The second compares different seconds of a flight, "
             "which differ in difficulty: the healthy twin's own post/pre ratio spreads as the last column shows. "
             f"Each flight: 100 s of {PROFILE_TEXT.get(f.get('profile', 'random_steps'), f.get('profile'))}.", "",
             "| fault (size) | runs | after / twin, adapted: median / worst | offline | recovery to 1.2x the "
             "twin (s) | within 1.2x of the twin from 10 s on | post/pre, adapted | recovery to 1.2x pre (s) "
             "| within 1.2x of pre from 10 s on | RMSE after the change, adapted / offline (rad/s, median) "
             "| thrust RMSE after the change, adapted / offline (N, median) "
             "| adapted at the end (median) | the twin's own post/pre |", "|---" * 13 + "|"]
    for name, rows in f["runs"].items():
        ok_twin = sum(r["adapted"]["vs_twin"] <= goal for r in rows)
        ok = sum(r["adapted"]["ratio"] <= goal for r in rows)
        prop = statistics.median(r["final"]["propeller_damage"] for r in rows) if rows else math.nan
        fric = statistics.median(r["final"]["bearing_friction"] for r in rows) if rows else math.nan
        twin = [r["adapted"]["twin_ratio"] for r in rows]
        lines.append(f"| {name} ({f['faults'][name]:g}) | {len(rows)} | "
                     f"{_median_worst([r['adapted']['vs_twin'] for r in rows])} | "
                     f"{_median_worst([r['offline']['vs_twin'] for r in rows])} | "
                     f"{_median_worst([r['adapted']['recovery_vs_twin_s'] for r in rows])} | {ok_twin}/{len(rows)} | "
                     f"{_median_worst([r['adapted']['ratio'] for r in rows])} | "
                     f"{_median_worst([r['adapted']['recovery_s'] for r in rows])} | {ok}/{len(rows)} | "
                     f"{_median([r['adapted']['post_rad_s'] for r in rows])} / "
                     f"{_median([r['offline']['post_rad_s'] for r in rows])} | "
                     f"{_median([r['adapted']['thrust_post_n'] for r in rows], 3)} / "
                     f"{_median([r['offline']['thrust_post_n'] for r in rows], 3)} | "
                     f"propeller loss {prop:.3f}, friction x{fric:.2f}{pack_change(rows)} | "
                     f"{min(twin):.2f} - {max(twin):.2f} |")
    told = {name: [r["told"]["vs_twin"] for r in rows] for name, rows in f["runs"].items()
            if rows and all("told" in r for r in rows)}
    if told:
        lines += ["", "The model told the change (its constants moved as the simulator moved the bench's, "
                  "`bench_adaptation.told`; no adapting; not a bearing's friction, whose fitted constant is no "
                  "reference: `bench_adaptation.TOLD`), its RMSE after the change over the offline twin's, median / "
                  f"worst and within {goal}x: "
                  + "; ".join(f"{name} {_median_worst(v)}, {sum(x <= goal for x in v)}/{len(v)}"
                              for name, v in told.items())
                  + ". Whether the model can hold the change at all: where the told model is within the goal and "
                  "the adapted one is not, the miss is the estimator's, not the model's."]
    h = f["healthy"]
    ok = sum(r["ratio"] <= goal_healthy for r in h)
    lines += ["", f"Healthy flights: {len(h)}; adapted / offline RMSE median / worst "
              f"{_median_worst([r['ratio'] for r in h])}; within {goal_healthy}x: {ok}/{len(h)}."]
    if f.get("health"):
        lines += ["", *_monitor_lines(f)]
    return lines


def _monitor_lines(f: dict[str, Any]) -> list[str]:
    """With ``--health``: what the monitor named (its first change after the onset, per fault) and
    what it reported on the flights without a change (the twins and the healthy flights)."""
    named = []
    for name, rows in f["runs"].items():
        first = [next((e for e in r["events"] if e["onset_s"] >= r["onset_s"] - 5.0), None) for r in rows]
        right = sum(e is not None and e["name"] == name for e in first)
        named.append(f"{name} {right}/{len(rows)}")
    taken = {"motor_heating": "{:.1f} K", "pack_resistance": "{:.2f}x",  # what the adapter is passed
             "propeller_damage": "{:.3f}", "bearing_friction": "{:.2f}x"}
    wrong = [f"{e['name']} in a {name} run (bench {r['bench']}: {taken[e['name']].format(e['size'])})"
             for name, rows in f["runs"].items() for r in rows for e in r["events"]
             if e["name"] in taken and e["name"] != name and e["size"] is not None]
    wrong_text = ", ".join(wrong) if wrong else "none"
    clean = [r["events_twin"] for rows in f["runs"].values() for r in rows] + [r["events"] for r in f["healthy"]]
    false = [e for events in clean for e in events]
    hours = len(clean) * f["flight_s"] / 3600.0
    return [f"With the health monitor watching (`--health`; a change it names is passed to the adapter, "
            f"`PhysicsAdapter.take_named`): the first change after the onset named right, {', '.join(named)}; "
            f"a change named in a run of another fault, and so passed to the adapter: {wrong_text}; "
            f"on the {len(clean)} flights without a change ({hours:.2f} h), {len(false)} change(s) reported"
            + (": " + "; ".join(f"{e['name']} {e['size']:.3g} {e['unit']} at {e['onset_s']:.1f} s" if e["size"]
                                is not None else f"{e['name']} at {e['onset_s']:.1f} s" for e in false)
               if false else "") + "."]


@dataclass(frozen=True)
class Group:
    """One group of figures: where they come from and how they are shown."""

    name: str
    title: str
    command: str  #: what produces docs/results/<name>.json (``--update`` runs it)
    render: Callable[[dict[str, Any]], list[str]]
    about: str  #: one sentence: what is measured, and how long it takes


GROUPS: dict[str, Group] = {g.name: g for g in [
    Group("demo", "The demo on the bundled bags", "python benchmarks/results.py --update demo", render_demo,
          "`scripts/demo.sh`'s steps 1-5 with `--json` (deterministic; a few minutes)."),
    Group("accuracy", "Accuracy of the three kinds on randomized benches",
          "taskset -c 1 python benchmarks/bench_accuracy.py --json docs/results/accuracy.json", render_accuracy,
          "Five benches drawn by `sim.random_bench` (seeds 0-4): train on staircases and ramps at seven charges, "
          "test on a 0.05-3 Hz chirp and a 25 % pack (about 4 minutes on one core)."),
    Group("accuracy_paper", "The network at the paper's size",
          "python benchmarks/bench_accuracy.py --seeds nominal --kinds network --size paper "
          "--json docs/results/accuracy_paper.json", render_accuracy,
          "The 3-25-1 network on 62,000 training patterns, the nominal bench (about a minute)."),
    Group("thrust_law", "The thrust law on real logs (`../shared/real/esc_test`)",
          "python benchmarks/bench_real.py --thrust-law-only --json docs/results/thrust_law.json", render_real,
          "b of T = b ω² fitted on each of the six logs (one DALPROP T7056 propeller, six ESC + motor pairs; "
          "seconds)."),
    Group("real", "Every kind on a real log (`../shared/real/esc_test`, the F80 log)",
          "python benchmarks/bench_real.py --jobs 1 --json docs/results/real.json",
          render_splits,
          "Every kind on the F80 log cut in three parts in time (about 4 minutes; it prints the thrust law too)."),
    Group("real_dropped", "The F80 log without the speed its thrust contradicts",
          "python benchmarks/bench_real.py --jobs 1 --drop-contradicted --json docs/results/real_dropped.json",
          render_splits,
          "As above with every piece imported with `--drop-contradicted`: no model is trained or scored on the "
          "speed the probe reads at 1100 µs, where the load cell holds a steady 19.5 gf (the rotor at about "
          "210-230 rad/s) and the supply draws 0.15 A more than with the ESC stopped, while the probe reads "
          "0-260 rad/s (about 4 minutes). Which import to prefer is the user's call (`import-csv` names the spans "
          "either way). Split 0 is scored on its way up without those rows. Split 2 is scored without its last "
          "1100 µs hold, where the model trained as read was 127 rad/s RMS off the probe's 0 (42 % of its squared "
          "error), but its model, trained without a speed at 1100 µs, fits another throttle map and Kv and "
          "extrapolates to the top of the staircase worse (each hold from 1700 µs up 51-144 rad/s too fast on "
          "average, against 28-95), and with it the health monitor names a bearing friction on the way down: a "
          "false alarm."),
    Group("real_f40", "Every kind on a second real log (`../shared/real/esc_test`, the F40 log)",
          "python benchmarks/bench_real.py --log f40 --jobs 1 --json docs/results/real_f40.json",
          render_splits,
          "As above on the ESC32v3 + F40 Pro III 1600 kv log with the same propeller, its 5 % duty steps taken "
          "from the ESC's own AutoQuad log (`import-csv --command-from`): the check that what holds on the F80 "
          "is not tuned to it (about 4 minutes). On its slow staircase every step up is a current the health "
          "monitor's reference never held, where its voltage fit extrapolates: a change no fault's signature "
          "explains, seen only at such currents, is kept as minor, not an alarm (a fault whose signature fits is "
          "still named), so on a log like this one the monitor cannot tell an unexplained change from its own "
          "extrapolation until the log comes back to currents it held."),
    Group("flight", "Another flight of the same vehicle, simulated (issue 29)",
          "python benchmarks/bench_flight.py --first-seed 980 --seeds 8 --jobs 2 --json docs/results/flight.json",
          render_flight,
          "Issue 29's goal on another flight of the same quad (hybrid at most 1 % of the range, network at most "
          "2 %) is stated on real flight logs the project does not have; this is its stand-in on benches drawn by "
          "`sim.random_bench` (never tuned on): every kind trained on pieces of one multirotor motor's flight "
          "(`--profile flight`) and scored on pieces of another, through `train` and `evaluate` (about 5 minutes "
          "on 2 cores). The recordings are the simulator's, not a log's ESC telemetry. The spread: eight more fresh "
          "benches (`--first-seed 990`, measured at ec0ef0c) gave hybrid 0.17 % [0.10, 0.25], 16 of 16 within 1 %; "
          "physics 0.19 % [0.10, 0.40]; network 2.44 % [1.22, 4.37], 6 of 16 within 2 %."),
    Group("cores", "Speed of the cores", "python benchmarks/bench_cores.py --json docs/results/cores.json",
          render_speed, "CPU time of the tachometer decoder, the battery filter and one estimator update per model "
          "kind, best of several runs (seconds; CPU time, so other load disturbs it little)."),
    Group("confusion_network", "Discrepancy, network path: the confusion table",
          "python experiments/confusion_table.py --seeds 10 --jobs 2 --json docs/results/confusion_network.json",
          render_confusion,
          "Every hidden effect and a control on benches drawn from each seed (about 30 minutes on 2 cores)."),
    Group("confusion_physics", "Discrepancy, physics path: the confusion table",
          "python experiments/physics_confusion.py --seeds 20 --jobs 2 --json docs/results/confusion_physics.json",
          render_confusion, "Every hidden effect and a control on benches drawn from each seed (about 3 minutes per "
          "seed on 2 cores). A start level between two commanded levels is not placed by the data: seed 50's "
          "esc_deadband, fitted at 2.58x the true strength, leaves the holdout at 1.4 rad/s, as a fit at 1.29x "
          "does."),
    Group("foreign_physics", "Discrepancy on a bench written by someone else, physics path",
          "python benchmarks/bench_foreign.py --first-seed 100 --seeds 3 --jobs 2 --path physics "
          "--json docs/results/foreign_physics.json", lambda f: render_foreign(f, "physics"),
          "`benchmarks/foreign_bench/`'s randomized benches, no CONFIG (about an hour on 2 cores); "
          "esc_deadband recorded from rest, as in the next group, which has six more benches of that case."),
    Group("foreign_deadband", "A start level from rest on a bench written by someone else, both paths",
          "python benchmarks/bench_foreign.py --first-seed 103 --seeds 6 --jobs 2 --path both --effects esc_deadband "
          "--json docs/results/foreign_deadband.json",
          lambda f: ["Physics path:", "", *render_foreign(f, "physics"), "", "Network path:", "",
                     *render_foreign(f, "network")],
          "esc_deadband alone, recorded from rest (`foreign_bench.scenarios.OWN_EXPERIMENT`: stops of 10-13 s where "
          "the project's experiment stops 0.5-1 s and these rotors coast 4-15 s, the low levels covered by bands), "
          "on benches never run before (about 50 minutes on 2 cores)."),
    Group("foreign_network", "Discrepancy on a bench written by someone else, network path",
          "python benchmarks/bench_foreign.py --first-seed 120 --seeds 8 --jobs 2 --path network "
          "--json docs/results/foreign_network.json", lambda f: render_foreign(f, "network"),
          "`benchmarks/foreign_bench/`'s randomized benches, never tuned on (about 30 minutes on 2 cores); "
          "`--trace` prints each run's workflow lines (scores, identification, each trial's holdout test)."),
    Group("health", "Health monitor in flight on randomized benches (issue 34)",
          "python benchmarks/bench_health.py --first-seed 840 --seeds 8 --flights 2 --hours 11 --jobs 2 "
          "--json docs/results/health.json", render_health,
          "Eight benches drawn by `sim.random_bench` (the seeds below, never tuned on), a physics model fitted on "
          "each from random steps on the bench; per bench 2 flights of a multirotor's motor with each fault "
          "(propeller_damage 0.1, pack_resistance 2x, motor_heating 30 K) and about 1.3 h of healthy flight, "
          "10.4 h in all (about 15 minutes on two cores). The spread between bench sets (the same command with "
          "another `--first-seed`), each as last measured; the record's own set first:\n\n"
          "| `--first-seed` | measured at | propeller_damage | pack_resistance | motor_heating "
          "| false alarms in 10.39 h |\n"
          "|---|---|---|---|---|---|\n"
          "| 840 (this record) | 5135399 | 16/16 | 16/16 | 15/16 | 0 |\n"
          "| 850 | 9e52286 | 11/16 | 15/16 | 11/16 | 0 |\n"
          "| 860 | 8fb8faa | 13/16 | 15/16 | 15/16 | 0 |\n"
          "| 870 | 77bad59 | 13/16 | 15/16 | 10/16 | 0 |\n"
          "| 890 | 0217125 | 12/16 | 16/16 | 14/16 | 2 (a) |\n"
          "| 900 | a5964b2 | 15/16 | 16/16 | 14/16 | 0 |\n"
          "| 910 | 8d6fe2f | 14/16 | 14/16 | 16/16 | 0 |\n"
          "| 920 | 93670b4 | 14/16 | 15/16 | 16/16 | 0 |\n"
          "| 930 | b496522 | 14/16 | 13/16 | 11/16 | 0 (b) |\n"
          "| 940 | 10d2589 | 14/16 | 15/16 | 15/16 | 0 (c) |\n"
          "| 950 | b496522 | 15/16 | 14/16 | 13/16 | 0 (d) |\n"
          "| 960 | 5135399 | 15/16 | 15/16 | 13/16 | 0 |\n\n"
          "Sets 930, 940 and 950 hold the flights the last three changes to the monitor were found on (b-d); "
          "840 and 960 do not. The false alarms, and what became of them: (a) bench 897, twice a propeller loss "
          "named and then reported with an earlier fit's size though the latest fit found it reversed: such a "
          "change is set aside as minor since, and those two flights raise none. (b) bench 935, a bearing "
          "friction named 1.76x at 56.5 s of a healthy flight (until b496522): a low hold inside the learned "
          "speeds, where the learned error, a cubic over 170-530 rad/s, said -0.4 rad/s and the model was -3.5 "
          "from the flight's first seconds on; the learned error is a penalised piecewise-linear fit since. "
          "(c) bench 944 at ec0ef0c, a bearing friction named 5.81x at 30.7 s (statistic 148): the voltage's "
          "noise learned from quiet blocks at 0.1-0.3 A only, 2 mV where the blocks at 3 A carry 25 mV; it is "
          "learned only once quiet blocks reach the currents tested since 10d2589. (d) bench 954 at 10d2589, "
          "a bearing friction named 2.0x at 39.1 s: the flight's first low hold, 1-5 % of the scale under the "
          "slowest speed the model's error was learned at, where the extrapolated error said -3 rad/s and the "
          "model was -6; since d0943c8 the learned error below its slowest speed only names a change found "
          "elsewhere. Heating is the fault found least surely: a 30 K rise moves the speed by a few rad/s at "
          "full load only, and the runs missed or left unnamed are those whose 5 s after the onset hold low "
          "loads, where heating and a bearing's friction look alike; which of them a change to the monitor "
          "finds moves by one or two per set (on this record's set, bench 845's at d0943c8, bench 847's at "
          "b496522). On set 960 two of the three heating runs missed had the speed untested for most of the 5 s "
          "after the onset (flights of fast manoeuvres, a third of their blocks steady: bench 967's speed was "
          "tested from 61.8 s, its onset at 56.4 s); the third (bench 965 at 74.2 s) held 0-4 steady blocks "
          "in those 5 s and its statistic peaked at 33.2 against 33.9."),
    Group("health_steps", "Health monitor on random steps on randomized benches (issue 34)",
          "python benchmarks/bench_health.py --first-seed 830 --seeds 8 --flights 2 --hours 11 --jobs 2 "
          "--profile random_steps --json docs/results/health_steps.json", render_health,
          "As above, the flights random steps over the whole range, the motor stopped at times (a bench's "
          "experiment, harder than a flight: a fault shows only while the rotor turns); about 15 minutes on two "
          "cores. The false alarm below (bench 834, a healthy flight at 230 s, an unnamed change that heating and "
          "friction explain alike) is an 8 s hold at full throttle over which the model's speed error fell "
          "steadily by 4 rad/s as the winding warmed: since the speed's drift and curvature have a prior of the "
          "flight's own size (77bad59) that fall at the window's end reads as a step; at a5c8402 the free "
          "curvature took it (no alarm in this flight). The spread between bench sets, each as last measured:\n\n"
          "| `--first-seed` | measured at | propeller_damage | pack_resistance | motor_heating "
          "| false alarms in 10.39 h |\n"
          "|---|---|---|---|---|---|\n"
          "| 830 (this record) | 64b4522 | 13/16 | 13/16 | 8/16 | 1 (the one above) |\n"
          "| 890 | 0217125 | 13/16 | 15/16 | 9/16 | 1 (a) |\n"
          "| 900 | a5964b2 | 12/16 | 13/16 | 12/16 | 1 (a) |\n"
          "| 910 | 8d6fe2f | 10/16 | 12/16 | 13/16 | 0 |\n"
          "| 920 | 93670b4 | 10/16 | 15/16 | 12/16 | 0 |\n"
          "| 930 | 14b38b2 | 10/16 | 14/16 | 8/16 | 3 (b) |\n"
          "| 940 | ec0ef0c | 11/16 | 14/16 | 8/16 | 0 |\n"
          "| 950 | 10d2589 | 10/16 | 15/16 | 11/16 | 0 |\n"
          "| 960 | b496522 | 11/16 | 14/16 | 9/16 | 1 (c) |\n\n"
          "A fault shows only while the rotor turns: most propeller losses late or missed had the rotor turning "
          "0.5-3.4 s of the 5 s after the onset; heating runs are left unnamed where heating and a bearing's "
          "friction explain the change alike. The false alarms: (a) bench 897 at 100 s and bench 905 at "
          "100.7 s, an unnamed change no signature fits: the pack's voltage at a rest after a burst, a few mV "
          "off what the reference's fitted polarisation and charge predict, on blocks of 3 mV noise; no fault "
          "changes the voltage at rest, and since 10ac397 no unstructured step is tested there (neither flight "
          "alarms since). (b) bench 935, a bearing friction named 2.07x at 64.3 s and an unnamed change at "
          "62.7 s, and bench 936, an unnamed change at 40.4 s (heating and friction explaining each alike); "
          "not measured again since. (c) bench 961, a healthy flight's winding named 50 K hotter at 33.8 s "
          "(statistic 51), from the voltage channel alone: at a 7.4 A hold after a burst to 11 A the terminal "
          "voltage rose 0.06-0.08 V over a few seconds, which the fitted polarisation did not follow. On this "
          "set the penalised learned error (b496522) found two propeller losses and two heating runs fewer than "
          "the cubic before it (13/16, 14/16, 11/16 at d0943c8)."),
    Group("band", "Uncertainty bands on held-out recordings (issue 34)",
          "taskset -c 1 python benchmarks/bench_band.py --seeds 3-10 --json docs/results/band.json", render_band,
          "Eight benches drawn by `sim.random_bench` (seeds 3-10), the three kinds trained as in the accuracy "
          "benchmark, each band fitted on the validation recordings only; coverage at one sigma on held-out "
          "recordings: a chirp, random steps, a staircase and a multirotor's motor in flight (about 10 minutes "
          "on one core)."),
    Group("adaptation", "Online adaptation in flight on randomized benches (issue 34)",
          "python benchmarks/bench_adaptation.py --seeds 4 --first-seed 308 --flights 2 "
          "--json docs/results/adaptation.json",
          render_adaptation,
          "Four benches drawn by `sim.random_bench` (seeds 308-311), a physics model fitted on each; per bench two "
          "100 s flights of a multirotor's motor with each change (propeller_damage 0.1, bearing_friction 3x, "
          "motor_heating 30 K, pack_resistance 2x) at a random onset, each also without it, and two healthy ones, "
          "predicted with and without `--adapt` (about 10 minutes)."),
    Group("adaptation_steps", "Online adaptation on random steps on randomized benches (issue 34)",
          "python benchmarks/bench_adaptation.py --seeds 4 --first-seed 308 --flights 2 --profile random_steps "
          "--json docs/results/adaptation_steps.json",
          render_adaptation,
          "As above on the same benches, the flights random steps over the whole range, the motor stopped at "
          "times (a bench's experiment)."),
    Group("adaptation_health", "Online adaptation with the health monitor, in flight (issue 34)",
          "python benchmarks/bench_adaptation.py --seeds 4 --first-seed 308 --flights 2 --health "
          "--json docs/results/adaptation_health.json",
          render_adaptation,
          "The flights of the adaptation in flight above, the health monitor watching too (`replay --adapt "
          "--health`, the node with both on): a change it names is taken into the adapted model "
          "(`PhysicsAdapter.take_named`): a hot winding as a set rise and a pack as a set resistance (the ohms "
          "the monitor found added; the adapted parameters back to before the onset), which the adapter "
          "cannot learn or learns slower; a propeller's loss or a bearing's friction as a restart "
          "of the adapted parameters from before the onset with the named size on its own, unless they "
          "explain the latest 3 s four times better; and a hot winding that has led a change still being "
          "named for 2 s, at once, provisionally (undone if the change is named otherwise or left unnamed; "
          "`HealthMonitor.leading`) (about 10 minutes on one core). A change being sized that another "
          "candidate comes to lead by the naming rule is renamed, and the adapter drops what the first name "
          "added; two flights here are (bench 311): 3110001, a tripled friction named motor_heating 1.4 s "
          "after its onset and bearing_friction 3.22x at 10.4 s (after the change, 1.58x the twin's RMSE), and "
          "3110102, a 30 K heating named bearing_friction at 69.9 s and motor_heating 22.8 K at 72.3 s (1.92x); "
          "the name counted below is the one reported."),
    Group("adaptation_health_steps", "Online adaptation with the health monitor, on random steps (issue 34)",
          "python benchmarks/bench_adaptation.py --seeds 4 --first-seed 308 --flights 2 --profile random_steps "
          "--health --json docs/results/adaptation_health_steps.json",
          render_adaptation,
          "The random steps of the adaptation on random steps above, the health monitor watching too."),
]}


# --- rendering the documents ---------------------------------------------------------------------------
HEADER = """# Current figures

Rendered by `python benchmarks/results.py` from `docs/results/<group>.json`; each JSON file was written
by the command its section names (with the date and commit), and `test/test_results_doc.py` checks
that this page is what the JSON renders to and recomputes the demo's figures. Earlier figures and
what changed them: [CHANGELOG.md](../CHANGELOG.md).
"""


def render_results_md(directory: Path = RESULTS_DIR) -> str:
    parts = [HEADER]
    for g in GROUPS.values():
        parts.append(f"## {g.title}\n")
        parts.append(f"{g.about}\n")
        rec = read_record(g.name, directory)
        if rec is None:
            parts.append(f"Not measured yet: run `{g.command}`, then `python benchmarks/results.py`.\n")
            continue
        parts.append(f"Command: `{rec['command']}`; {provenance(rec)}.\n")
        parts.append("\n".join(g.render(rec["figures"])) + "\n")
    return "\n".join(parts)


#: README regions: marker name -> (group, renderer)
README_REGIONS: dict[str, tuple[str, Callable[[dict[str, Any]], list[str]]]] = {
    "demo": ("demo", render_demo_readme),
}


def region_markers(name: str) -> tuple[str, str]:
    return f"<!-- results:{name}:begin -->", f"<!-- results:{name}:end -->"


def render_readme(text: str, directory: Path = RESULTS_DIR) -> str:
    """The README with every results region replaced by its rendering (the rest untouched)."""
    for name, (group, renderer) in README_REGIONS.items():
        begin, end = region_markers(name)
        if text.count(begin) != 1 or text.count(end) != 1:
            raise BadInputError(f"README.md: needs one {begin} and one {end}")
        head, rest = text.split(begin, 1)
        _, tail = rest.split(end, 1)
        rec = read_record(group, directory)
        body = (render_lines_with_source(rec, renderer) if rec is not None
                else [f"Not measured yet: run `{GROUPS[group].command}`."])
        text = head + begin + "\n" + "\n".join(body) + "\n" + end + tail
    return text


def render_lines_with_source(rec: dict[str, Any], renderer: Callable[[dict[str, Any]], list[str]]) -> list[str]:
    """A region's rendering and, under it, the command that produced it and where the rest is."""
    return [*renderer(rec["figures"]), "",
            f"(`{rec['command']}`, {rec['date']};",
            "every figure and its command: [docs/results.md](docs/results.md).)"]


def render_all(check: bool) -> int:
    """Write (or with ``check`` compare) docs/results.md and the README; 1 if a check failed."""
    wanted = {RESULTS_MD: render_results_md(), README: render_readme(README.read_text(encoding="utf-8"))}
    stale = [p for p, text in wanted.items() if not p.is_file() or p.read_text(encoding="utf-8") != text]
    if check:
        for p in stale:
            print(f"{p.relative_to(ROOT)}: not what docs/results/*.json renders to (run python benchmarks/results.py)",
                  file=sys.stderr)
        return 1 if stale else 0
    for p in stale:
        p.write_text(wanted[p], encoding="utf-8")
        print(f"wrote {p.relative_to(ROOT)}")
    return 0


def update(name: str) -> None:
    g = GROUPS[name]
    if name == "demo":
        produce_demo(RESULTS_DIR / "demo.json")
        return
    argv = shlex.split(g.command)
    argv[argv.index("python")] = sys.executable
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = RESULTS_DIR / f"{name}.json"
    before = out.stat().st_mtime_ns if out.exists() else None
    proc = subprocess.run(argv, cwd=ROOT, env=env)
    written = out.exists() and out.stat().st_mtime_ns != before
    if proc.returncode != 0 and not written:
        raise BadInputError(f"--update {name}: `{g.command}` exited {proc.returncode} and wrote no figures")
    if proc.returncode != 0:  # bench_real.py exits 1 when a goal is missed: its figures still stand
        print(f"--update {name}: `{g.command}` exited {proc.returncode} (a goal missed?); its figures were written",
              file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--update", nargs="+", metavar="GROUP", default=[],
                    help=f"rerun these groups' commands first (groups: {', '.join(GROUPS)})")
    ap.add_argument("--check", action="store_true", help="render nothing; exit 1 if a document is stale")
    ap.add_argument("--list", action="store_true", help="print each group's command and stop")
    args = ap.parse_args(argv)
    if args.list:
        for g in GROUPS.values():
            print(f"{g.name:18s} {g.command}")
        return 0
    unknown = [n for n in args.update if n not in GROUPS]
    if unknown:
        raise BadInputError(f"--update: unknown group(s) {', '.join(unknown)} (groups: {', '.join(GROUPS)})")
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    for name in args.update:
        update(name)
    return render_all(args.check)


if __name__ == "__main__":
    try:
        sys.exit(main())
    except BadInputError as exc:
        print(f"results: error: {exc}", file=sys.stderr)
        sys.exit(2)
