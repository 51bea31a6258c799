"""Report figures: each writes a real PNG; the index shows them and escapes text; edge cases."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from bldc_propulsion.training import report

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def assert_png(path: Path) -> np.ndarray:
    assert path.is_file(), path
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100 and img.shape[2] in (3, 4)
    assert not list(path.parent.glob(".*partial*")), "staging left behind"
    return img


@pytest.fixture()
def signals() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 20.0, 0.01)
    pwm = np.where((t % 8) < 4, 0.06, 0.08) + 0.002 * np.sin(t)
    speed = 4000.0 * (pwm - 0.05)
    pred = speed + rng.normal(0.0, 5.0, t.size)
    volts = 12.4 - 0.02 * t
    return {"t": t, "pwm": pwm, "speed": speed, "pred": pred, "volts": volts}


def test_every_figure_is_a_valid_png(tmp_path: Path, signals: dict[str, np.ndarray]) -> None:
    s = signals
    t_raw = np.arange(0.0, 20.0, 0.001)  # 1 kHz: longer than the envelope limit
    raw = 12.4 + 1.5 * np.sign(np.sin(2 * np.pi * 97 * t_raw))
    filt = np.full_like(t_raw, 12.4)
    outs = [
        report.fig_battery_filter(t_raw, raw, filt, tmp_path / "f1.png"),
        report.fig_battery_filter(t_raw, raw, filt, tmp_path / "f1b.png", pwm_t=s["t"], pwm=s["pwm"]),
        report.fig_ramp(s["t"], s["pwm"], s["speed"], tmp_path / "f5.png"),
        report.fig_training(np.geomspace(1.0, 1e-3, 40), np.geomspace(1.2, 2e-3, 40), 35, tmp_path / "f12.png"),
        report.fig_validation(s["t"], s["pwm"], s["volts"], s["speed"], s["pred"], tmp_path / "f13.png",
                              title="chirp <test> & co"),
        report.fig_prediction_scatter(s["speed"], s["pred"], tmp_path / "scatter.png"),
        report.fig_disagreement_map(s["pwm"], np.gradient(s["pwm"], s["t"]), s["speed"] - s["pred"],
                                    tmp_path / "map.png", voltage=s["volts"]),
        report.fig_before_after(s["t"], s["speed"], s["pred"] + 30.0, s["pred"], tmp_path / "ba.png",
                                windows=[(2.0, 4.0), (10.0, 11.5)]),
    ]
    for out in outs:
        assert isinstance(out, Path)
        assert_png(out)
    # Fig. 1 + Fig. 2 is taller than Fig. 1 alone
    assert mpimg.imread(outs[1]).shape[0] > mpimg.imread(outs[0]).shape[0]


def test_figure_replaces_an_older_one(tmp_path: Path, signals: dict[str, np.ndarray]) -> None:
    out = tmp_path / "f5.png"
    out.write_bytes(b"old")
    report.fig_ramp(signals["t"], signals["pwm"], signals["speed"], out)
    assert_png(out)


def test_disagreement_map_edge_cases(tmp_path: Path) -> None:
    # constant input: every sample in one bin, no rate of change
    n = 200
    report.fig_disagreement_map(np.full(n, 0.07), np.zeros(n), np.full(n, 3.0), tmp_path / "const.png",
                                voltage=np.full(n, 12.0))
    # empty input
    report.fig_disagreement_map(np.array([]), np.array([]), np.array([]), tmp_path / "empty.png",
                                voltage=np.array([]))
    # all bins below the minimum count, NaNs, and zero residual
    x = np.array([0.06, 0.07, np.nan, 0.08])
    report.fig_disagreement_map(x, np.array([0.0, 1.0, 2.0, np.inf]), np.zeros(4), tmp_path / "sparse.png")
    for name in ("const.png", "empty.png", "sparse.png"):
        assert_png(tmp_path / name)


def test_binned_mean_truth() -> None:
    pwm = np.array([0.06] * 10 + [0.08] * 10 + [0.08] * 2)
    rate = np.array([0.0] * 10 + [0.0] * 10 + [1.0] * 2)
    res = np.array([2.0] * 10 + [-4.0] * 10 + [100.0] * 2)
    ex, ey, mean, counts = report.binned_mean_2d(pwm, rate, res, bins=(2, 2), min_count=5)
    assert counts.sum() == 22
    assert mean[0, 0] == pytest.approx(2.0) and mean[1, 0] == pytest.approx(-4.0)
    assert mean.mask[1, 1] and counts[1, 1] == 2  # two samples: masked, not shown
    assert mean.mask[0, 1] and counts[0, 1] == 0  # empty bin


def test_other_figures_tolerate_degenerate_input(tmp_path: Path) -> None:
    e = np.array([])
    report.fig_training([], [], None, tmp_path / "t0.png")
    report.fig_training([1.0, 0.0, np.nan], [], 7, tmp_path / "t1.png")  # zero, NaN, epoch past the end
    report.fig_prediction_scatter(e, e, tmp_path / "s0.png")
    report.fig_prediction_scatter(np.full(5, 100.0), np.full(5, 100.0), tmp_path / "s1.png")
    report.fig_validation(e, e, e, e, e, tmp_path / "v0.png")
    report.fig_before_after(e, e, e, e, tmp_path / "b0.png", windows=[(1.0, float("nan"))])
    report.fig_battery_filter(e, e, e, tmp_path / "f0.png")
    for name in ("t0", "t1", "s0", "s1", "v0", "b0", "f0"):
        assert_png(tmp_path / f"{name}.png")


def test_index_references_every_figure_and_escapes_text(tmp_path: Path, signals: dict[str, np.ndarray]) -> None:
    s = signals
    report.fig_ramp(s["t"], s["pwm"], s["speed"], tmp_path / "fig05_ramp.png")
    report.fig_prediction_scatter(s["speed"], s["pred"], tmp_path / "scatter 1.png")
    figures = [
        ("fig05_ramp.png", "Figs. 5-6: ramp <b>bold</b> & more"),
        (str(tmp_path / "scatter 1.png"), 'scatter of "run" <script>alert(1)</script>'),
    ]
    rows = [
        {"path": "a<b>.bag", "rmse_rad_s": 12.3456789, "n": 3, "ok": True, "note": None},
        {"path": "c&d.bag", "rmse_rad_s": float("nan"), "extra": [1.0, 2.5]},
    ]
    index = report.write_index(tmp_path, "Report <1> & 2", figures, [("per <recording>", rows)])
    assert index == tmp_path / "index.html"
    text = index.read_text(encoding="utf-8")
    assert 'src="fig05_ramp.png"' in text
    assert 'src="scatter%201.png"' in text  # absolute path inside the report -> relative
    for _, caption in figures:
        assert caption not in text  # raw markup never appears
    assert "&lt;script&gt;" in text and "<script>" not in text
    assert "Report &lt;1&gt; &amp; 2" in text
    assert "per &lt;recording&gt;" in text and "a&lt;b&gt;.bag" in text and "c&amp;d.bag" in text
    assert "12.3457" in text and "extra" in text and "1, 2.5" in text
    assert text.count("<img ") == 2 and text.count("<tr>") == 3
    for name in ("fig05_ramp.png", "scatter 1.png"):
        assert (tmp_path / name).is_file()
    # rewriting the index replaces it
    report.write_index(tmp_path, "again", figures[:1])
    assert "again" in index.read_text(encoding="utf-8")


def test_band_error_figure(tmp_path: Path) -> None:
    """The per-band error as a figure (bars labelled with % of range), and a clear 'no bands'."""
    bands = [{"low_hz": 0.0, "high_hz": 0.5, "samples": 900, "rmse_rad_s": 8.2, "rmse_percent_of_range": 1.66},
             {"low_hz": 0.5, "high_hz": 1.0, "samples": 500, "rmse_rad_s": 19.0, "rmse_percent_of_range": 3.9}]
    assert_png(report.fig_band_error(bands, tmp_path / "bands.png", recording="bags/chirp"))
    assert_png(report.fig_band_error([], tmp_path / "none.png", recording="bags/staircase"))


def test_before_after_shows_measured_before_and_after_distinctly(
        tmp_path: Path, signals: dict[str, np.ndarray], monkeypatch: pytest.MonkeyPatch) -> None:
    """The before/after figure (issue 12: the measured line was hidden under the models): three
    distinct lines, measured a wider band beneath the models so that a model that matches it
    exactly leaves it visible, a legend naming all three, the recording named, axes that fit
    the data (not the shaded windows), and errors whose RMSE labels are the known offsets.
    Checked on the figure's own Axes (kept when it is saved), not on pixels."""
    saved = []
    save = report._save
    monkeypatch.setattr(report, "_save", lambda fig, out: (saved.append(fig), save(fig, out))[1])
    t, measured = signals["t"], signals["speed"]
    before, after = measured + 30.0, measured.copy()  # after = measured exactly: the worst case
    out = report.fig_before_after(t, measured, before, after, tmp_path / "ba.png",
                                  windows=[(2.0, 4.0), (18.0, 40.0)], recording="flight <7>.mcap")
    assert_png(out)
    (fig,) = saved
    top, bottom = fig.axes[:2]
    lines = {ln.get_label(): ln for ln in top.get_lines()}
    assert set(lines) == {"measured", "model before", "model after"}
    for label, y in (("measured", measured), ("model before", before), ("model after", after)):
        assert np.array_equal(lines[label].get_xdata(), t) and np.array_equal(lines[label].get_ydata(), y)
    styles = {label: (ln.get_color(), ln.get_linestyle()) for label, ln in lines.items()}
    assert len(set(v[0] for v in styles.values())) == 3, styles  # three colours
    assert styles["model before"][1] != styles["model after"][1], styles  # and not one line style
    m, models = lines["measured"], [lines["model before"], lines["model after"]]
    assert all(m.get_zorder() < ln.get_zorder() for ln in models)  # beneath ...
    assert all(m.get_linewidth() >= 2.5 * ln.get_linewidth() for ln in models)  # ... and wider
    legend = [x.get_text() for x in top.get_legend().get_texts()]
    assert {"measured", "model before", "model after", "disagreement window"} <= set(legend)
    # axes fit the data: the time span exactly (the window to 40 s does not widen it), the
    # speeds with a margin of at most 10 % of their range
    assert top.get_xlim() == pytest.approx((t.min(), t.max()))
    lo, hi = min(measured.min(), before.min()), max(measured.max(), before.max())
    y0, y1 = top.get_ylim()
    assert y0 <= lo and y1 >= hi and (y1 - y0) <= 1.1 * (hi - lo)
    errors = {ln.get_label(): ln for ln in bottom.get_lines() if not ln.get_label().startswith("_")}
    assert set(errors) == {"before (RMSE 30.0 rad/s)", "after (RMSE 0.0 rad/s)"}
    assert np.allclose(errors["before (RMSE 30.0 rad/s)"].get_ydata(), -30.0)
    named = [top.get_title()] + [x.get_text() for x in fig.texts]
    assert any("flight <7>.mcap" in x for x in named) and "flight <7>.mcap" in top.get_title()
