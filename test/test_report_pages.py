"""Report pages a person reads at a glance (issue 31, item 6): the training page states its RMSE
(rad/s and % of range), b with its source and the learning curve; a thrust figure wherever the
recording has /thrust/measured and the model a b, whose stated RMSE is the recording's (by hand);
an index of reports with a thumbnail and the headline numbers of each, equal to the --json
figures; titles that say what the command is; the screenshot script.

Small simulated recordings (6 s), a 3-3-1 network trained for a few epochs, all in-process.
"""

from __future__ import annotations

import html
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from _scripts import load_script
from _truth_bags import write_bag
from bldc_propulsion import cli
from bldc_propulsion.model import load_model
from bldc_propulsion.recordings import load_signals
from bldc_propulsion.training import report
from bldc_propulsion.training.evaluate import predict_speed
from bldc_propulsion.training.train import features_of

ROOT = Path(__file__).resolve().parents[1]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
SMALL = ("--hidden", "3", "--max-epochs", "8", "--restarts", "1")


def run_cli(capsys: pytest.CaptureFixture[str], *args: object) -> dict:
    """``bldc-propulsion ARGS --json`` in this process; its JSON object (exit 0 asserted)."""
    code = cli.main([str(a) for a in args] + ["--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


def page_text(index: Path) -> str:
    return html.unescape(index.read_text(encoding="utf-8"))


def headline(index: Path) -> dict[str, str]:
    """The page's headline as label -> text (from the <dl class="headline"> it writes)."""
    raw = index.read_text(encoding="utf-8")
    block = re.search(r'<dl class="headline">(.*?)</dl>', raw, re.S)
    assert block, "no headline on the page"
    pairs = re.findall(r"<dt>(.*?)</dt><dd>(.*?)</dd>", block.group(1), re.S)
    return {html.unescape(k): html.unescape(v) for k, v in pairs}


def images(index: Path) -> list[str]:
    return re.findall(r'<img src="([^"]+)"', index.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("report_bags")
    return {"train": write_bag(d / "train", "random_steps", 5, thrust=True),
            "val": write_bag(d / "val", "random_steps", 6, thrust=True),
            "test": write_bag(d / "test", "random_steps", 7, thrust=True),
            "train_plain": write_bag(d / "train_plain", "random_steps", 3, thrust=False),
            "val_plain": write_bag(d / "val_plain", "random_steps", 4, thrust=False)}


@pytest.fixture(scope="module")
def trained(bags: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A model trained on recordings with thrust, with its report and --json."""
    d = tmp_path_factory.mktemp("trained")
    code = cli.main([str(a) for a in ("train", bags["train"], "--validation", bags["val"], "-o", d / "m.npz",
                                      *SMALL, "--report", d / "report_train", "--json")])
    assert code == 0
    return {"dir": d, "model": d / "m.npz", "report": d / "report_train"}


# --- the training page ---------------------------------------------------------------------------

def test_training_page_states_rmse_b_and_the_learning_curve(bags, tmp_path, capsys):
    out = tmp_path / "m.npz"
    data = run_cli(capsys, "train", bags["train"], "--validation", bags["val"], "-o", out, *SMALL,
                   "--report", tmp_path / "rep")
    index = tmp_path / "rep" / "index.html"
    head = headline(index)
    model = load_model(out)
    train, val = load_signals(str(bags["train"])), load_signals(str(bags["val"]))
    # the RMSE by hand from the saved model (the network's output on the samples whose inputs are
    # known, as training scores it), and its % of each recording's speed range
    for key, label, sig in (("train", "training", train), ("validation", "validation", val)):
        X = features_of(sig, model.input_names, model.feature_params())
        ok = np.all(np.isfinite(X), axis=1) & np.isfinite(sig.speed)
        rmse = float(np.sqrt(np.mean((model.forward(X[ok]) - sig.speed[ok]) ** 2)))
        assert data[f"{key}_rmse_rad_s"] == pytest.approx(rmse, rel=1e-6)
        span = float(np.ptp(sig.speed))
        assert data[f"{key}_rmse_percent_of_range"] == pytest.approx(100.0 * rmse / span, rel=1e-6)
        assert head[f"{label} RMSE"].startswith(
            f"{rmse:.2f} rad/s ({100.0 * rmse / span:.2f} % of the {span:.0f} rad/s range)"), head
    # b: the least-squares fit on the training recording's thrust, by hand, and its source
    b = float(np.dot(train.speed**2, train.thrust) / np.dot(train.speed**2, train.speed**2))
    assert model.thrust_coefficient == pytest.approx(b, rel=1e-9)
    assert data["thrust_coefficient"] == model.thrust_coefficient
    assert head["thrust coefficient b"].startswith(f"{b:.4g} N s²/rad² (from least squares on /thrust/measured")
    assert head["model"].startswith(f"network 3-3-1 on battery_voltage, pwm, pwm_filtered: {data['epochs']} epochs")
    # the learning curve, the validation figure and the thrust figure are on the page, as PNGs
    srcs = images(index)
    for name in ("fig12_training.png", "fig13_validation_0.png", "thrust_validation_0.png", "fig05_ramp.png"):
        assert name in srcs and (tmp_path / "rep" / name).read_bytes()[:8] == PNG_SIGNATURE, name
    assert "learning curve" in page_text(index)
    # the thrust on the validation recording, by hand
    pred = b * predict_speed(model, val) ** 2
    rmse_n = float(np.sqrt(np.mean((val.thrust - pred) ** 2)))
    span_n = float(np.ptp(val.thrust))
    assert head[f"thrust, validation {bags['val']}"] == \
        f"RMSE {rmse_n:.3f} N ({100 * rmse_n / span_n:.1f} % of the {span_n:.2f} N thrust range)"


def test_training_page_without_thrust_says_b_is_not_known(bags, tmp_path, capsys):
    data = run_cli(capsys, "train", bags["train_plain"], "--validation", bags["val_plain"], "-o", tmp_path / "m.npz",
                   *SMALL, "--report", tmp_path / "rep")
    assert data["thrust_coefficient"] is None
    index = tmp_path / "rep" / "index.html"
    assert headline(index)["thrust coefficient b"].startswith("not known (none: no thrust measured or stated)")
    assert "no thrust figure: the model has no thrust coefficient b" in page_text(index)
    assert not list((tmp_path / "rep").glob("thrust_*.png"))


# --- the thrust figure ---------------------------------------------------------------------------

def test_thrust_error_by_hand() -> None:
    m, p = [0.0, 1.0, 2.0, 3.0, np.nan], [0.0, 1.0, 2.0, 5.0, 1.0]
    rmse, span, pct = report.thrust_error(m, p)  # the NaN sample is left out: errors 0, 0, 0, -2
    assert (rmse, span, pct) == pytest.approx((1.0, 3.0, 100.0 / 3.0))
    assert report.thrust_error_text(m, p) == "RMSE 1.000 N (33.3 % of the 3.00 N thrust range)"


def test_evaluate_report_thrust_figure_states_the_recordings_rmse(trained, bags, tmp_path, capsys, monkeypatch):
    titles: dict[str, list[str]] = {}
    save = report._save

    def keep_titles(fig, out):  # the figure's own text, read before it is saved and freed
        titles[Path(out).name] = [ax.get_title() for ax in fig.axes]
        return save(fig, out)

    monkeypatch.setattr(report, "_save", keep_titles)
    data = run_cli(capsys, "evaluate", "--model", trained["model"], bags["test"], "--report", tmp_path / "rep")
    rec = data["recordings"][0]
    model, sig = load_model(trained["model"]), load_signals(str(bags["test"]))
    # by hand: b w^2 of the predicted speed against the load cell
    pred = model.thrust_coefficient * predict_speed(model, sig) ** 2
    rmse_n = float(np.sqrt(np.mean((sig.thrust - pred) ** 2)))
    span_n = float(np.ptp(sig.thrust))
    assert rec["thrust_rmse_n"] == pytest.approx(rmse_n, rel=1e-9)
    assert rec["thrust_range_n"] == pytest.approx(span_n, rel=1e-9)
    assert rec["thrust_rmse_percent_of_range"] == pytest.approx(100.0 * rmse_n / span_n, rel=1e-9)
    stated = f"RMSE {rmse_n:.3f} N ({100 * rmse_n / span_n:.1f} % of the {span_n:.2f} N thrust range)"
    assert titles["thrust_0.png"][1] == f"thrust error measured - predicted: {stated}"
    assert str(bags["test"]) in titles["thrust_0.png"][0]
    index = tmp_path / "rep" / "index.html"
    assert "thrust_0.png" in images(index)
    head = headline(index)
    assert head[f"thrust, {bags['test']}"] == stated
    assert head[f"speed, {bags['test']}"].startswith(
        f"RMSE {rec['rmse_rad_s']:.2f} rad/s ({rec['rmse_percent_of_range']:.2f} % of the")
    assert head["overall speed RMSE"] == f"{data['rmse_rad_s']:.2f} rad/s"


def test_evaluate_report_without_thrust_says_why(trained, bags, tmp_path, capsys):
    run_cli(capsys, "evaluate", "--model", trained["model"], bags["val_plain"], "--report", tmp_path / "rep")
    index = tmp_path / "rep" / "index.html"
    assert headline(index)[f"thrust, {bags['val_plain']}"] == "no figure: no /thrust/measured in the recording"
    assert not list((tmp_path / "rep").glob("thrust_*.png"))


# --- the index of reports ------------------------------------------------------------------------

def test_index_of_reports_has_a_thumbnail_and_the_headline_of_each(trained, bags, tmp_path, capsys):
    demo = tmp_path / "demo"
    demo.mkdir()
    shutil.copytree(trained["report"], demo / "report_train")
    ev = run_cli(capsys, "evaluate", "--model", trained["model"], bags["test"], "--report", demo / "report_eval")
    # a discrepancy report as discrepancy/results.py writes it (its tables' captions and columns,
    # no headline of its own)
    report.fig_ramp(np.arange(10.0), np.full(10, 0.07), np.full(10, 300.0), tmp_path / "x.png")
    disc = demo / "report_discrepancy"
    disc.mkdir()
    shutil.copy(tmp_path / "x.png", disc / "disagreement_map.png")
    new = "added (new in the measured data)"
    gap = {"holdout RMSE before": 60.8212, "after": 23.6349, "in windows before": None, "in windows after": None}
    report.write_index(disc, "discrepancy: esc_deadband", [("disagreement_map.png", "map")],
                       [("candidate effects: what each ended as", [{"effect": "esc_deadband", "status": new}]),
                        ("added: the test that decided each", [{"effect": "esc_deadband", "status": new}]),
                        ("not added (structural, or considered, not added)",
                         [{"effect": "rotor_lag", "status": "considered, not added", "why": "too small"},
                          {"effect": "battery_voltage", "status": "structural", "why": "on the reference too"},
                          {"effect": "input_delay", "why": "no status column"}]),
                        ("the gap", [gap])])
    code = report.main(["demo-index", str(demo), "report_train=1. training", "report_eval=3. evaluation",
                        "report_discrepancy=4. discrepancy", "report_missing=5. not run"])
    assert code == 0
    index = demo / "index.html"
    raw = index.read_text(encoding="utf-8")
    sections = re.findall(r'<section class="step">(.*?)</section>', raw, re.S)
    assert len(sections) == 4
    for section, folder in zip(sections[:3], ("report_train", "report_eval", "report_discrepancy"), strict=True):
        (src,) = re.findall(r'<img src="([^"]+)"', section)  # one thumbnail per step ...
        assert src.startswith(folder + "/") and (demo / src).read_bytes()[:8] == PNG_SIGNATURE  # ... a real PNG
        assert f'href="{folder}/index.html"' in section
    assert "<img" not in sections[3] and "no report in report_missing/" in sections[3]
    assert images(demo / "report_train" / "index.html")[0] in sections[0]  # the report's main figure
    text = html.unescape(raw)
    # the headline numbers are the reports' own figures: training (from report.json, checked
    # against the --json by the training-page test), evaluation (its --json) and the gap
    train_json = json.loads((demo / "report_train" / report.REPORT_JSON).read_text())
    train_head = {h["label"]: h["text"] for h in train_json["headline"]}
    assert train_head["training RMSE"] in text and train_head["thrust coefficient b"] in text
    assert f"{ev['rmse_rad_s']:.2f} rad/s" in html.unescape(sections[1])
    assert f"{ev['recordings'][0]['thrust_rmse_n']:.3f} N" in html.unescape(sections[1])
    assert "holdout RMSE before → after</dt><dd>60.82 → 23.63 rad/s" in html.unescape(sections[2])
    assert "effects added</dt><dd>esc_deadband (new in the measured data)</dd>" in html.unescape(sections[2])
    assert "not added</dt><dd>rotor_lag, battery_voltage (structural), input_delay</dd>" in html.unescape(sections[2])
    # bad input: one line, exit 2
    assert report.main(["demo-index", str(tmp_path / "nowhere")]) == 2
    assert report.main(["demo-index", str(demo), "no_equals_sign"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "nowhere: not a directory" in err[0] and "expected FOLDER=TEXT" in err[1]


def test_report_json_mirrors_the_page(tmp_path: Path) -> None:
    report.fig_ramp(np.arange(10.0), np.full(10, 0.07), np.full(10, 300.0), tmp_path / "a b.png")
    report.write_index(tmp_path, "t <1>", [("a b.png", "cap & x")],
                       [("rows", [{"x": float("nan"), "y": np.float64(2)}])],
                       headline=[("RMSE <a>", "1.00 rad/s")], notes=["no <thrust>"])
    data = json.loads((tmp_path / report.REPORT_JSON).read_text())
    assert data["title"] == "t <1>" and data["headline"] == [{"label": "RMSE <a>", "text": "1.00 rad/s"}]
    assert data["figures"] == [{"file": "a%20b.png", "caption": "cap & x"}] and data["notes"] == ["no <thrust>"]
    assert data["tables"] == [{"caption": "rows", "rows": [{"x": None, "y": 2.0}]}]
    raw = (tmp_path / "index.html").read_text()
    assert "RMSE &lt;a&gt;" in raw and "no &lt;thrust&gt;" in raw and "<thrust>" not in raw


# --- titles that say what the data is ------------------------------------------------------------

def test_the_command_is_described_by_what_it_is() -> None:
    t = np.arange(0.0, 40.0, 0.01)
    stairs = 0.05 + 0.005 * np.minimum(np.floor(t / 2.5), 8)  # 9 levels, 2.5 s each, the last 20 s
    assert report.describe_command(t, stairs) == "held in 9 steps between 0.050 and 0.090"
    tri = 0.05 + 0.045 * (1 - np.abs((t % 20.0) / 10.0 - 1.0))  # up 10 s, down 10 s
    tri = np.round(tri * 2000) / 2000  # held between 50 Hz updates, as a command is
    assert report.describe_command(t, np.repeat(tri[::2], 2)[: len(t)]).startswith("ramps between 0.050 and")
    chirp = 0.07 + 0.02 * np.sin(2 * np.pi * (0.05 * t + 0.04 * t**2))
    assert report.describe_command(t, chirp).startswith("a varying command between")
    assert report.describe_command([], []) == "no command recorded"


def test_ramp_figure_titles_a_staircase_as_steps(tmp_path, monkeypatch) -> None:
    titles = []
    save = report._save
    monkeypatch.setattr(report, "_save", lambda fig, out: (titles.extend(ax.get_title() for ax in fig.axes),
                                                          save(fig, out))[1])
    t = np.arange(0.0, 20.0, 0.01)
    report.fig_ramp(t, 0.05 + 0.01 * np.floor(t / 5.0), 100 * np.floor(t / 5.0), tmp_path / "f.png")
    assert titles[0] == "PWM command: held in 4 steps between 0.050 and 0.080"
    assert not any("sweeping" in x for x in titles)


# --- the screenshot script -----------------------------------------------------------------------

def _screenshot_script():
    return load_script("scripts/screenshot_reports.py", "screenshot_reports")


def test_screenshot_script_finds_pages_and_skips_without_chromium(tmp_path, capsys, monkeypatch):
    mod = _screenshot_script()
    for sub in ("", "report_a", "report_b/inner"):
        (tmp_path / sub).mkdir(parents=True, exist_ok=True)
        (tmp_path / sub / "index.html").write_text("<html></html>")
    pages = mod.pages(tmp_path)
    assert [mod.shot_name(tmp_path, p) for p in pages] == ["index.png", "report_a.png", "report_b_inner.png"]
    monkeypatch.setattr(mod, "find_chromium", lambda: None)
    assert mod.main([str(tmp_path), str(tmp_path / "shots")]) == 0
    assert "skipped: no Chromium found (install it with `apt-get install -y chromium`)" in capsys.readouterr().out
    assert not (tmp_path / "shots").exists()
    assert mod.main([str(tmp_path / "absent"), str(tmp_path / "shots")]) == 2


@pytest.mark.skipif(_screenshot_script().find_chromium() is None, reason="no Chromium (not needed in CI)")
def test_screenshot_of_a_report_page(trained, tmp_path, capsys):
    import matplotlib.image as mpimg

    mod = _screenshot_script()
    assert mod.main([str(trained["report"]), str(tmp_path)]) == 0
    img = mpimg.imread(tmp_path / "index.png")
    assert img.shape[:2] == (2000, 1280)
    assert float(np.std(img[..., :3])) > 0.05  # a rendered page, not a blank one
