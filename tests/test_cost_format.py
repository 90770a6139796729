"""The scene estimate's durations read as plain numbers (no exponent: '1.5e+02 ms' looked like a misprint)."""

from lieseries.cost import CostPart, SceneEstimate


def test_durations_below_a_second_print_without_exponent():
    cases = {0.15: "150 ms", 0.0999: "100 ms", 0.0012: "1.2 ms", 0.9996: "1000 ms", 4.5e-4: "450 us",
             2.5e-6: "2.5 us"}
    for seconds, text in cases.items():
        part = CostPart("run.samples", "100 output times", 100, "time", seconds, "measured")
        assert part.describe() == f"100 output times at ~{text} each"
    est = SceneEstimate("s", parts=[CostPart("run.samples", "100 output times", 100, "time", 0.15, "measured")])
    assert est.summary() == "estimated 15 s: 100 output times at ~150 ms each (`run.samples`)"


def test_a_part_bounded_below_reads_as_such():
    part = CostPart("run.t", "the reference", 1, "run", 3.9, "timed", lower_bound=True)
    assert part.describe() == "the reference at no less than 3.9 s each"  # it read "at at least 3.9 s"
    assert SceneEstimate("s", parts=[part]).summary().startswith("estimated at least 3.9 s: ")


def test_scientific_notation_beyond_a_doubles_range_keeps_the_exponent():
    """An error of 1e-402 (an mpf or a Fraction) read as a float is 0: the report would print "0", exact."""
    from fractions import Fraction

    import mpmath

    from lieseries.formatting import fmt_sci

    c = mpmath.MPContext()
    c.dps = 500
    assert fmt_sci(c.mpf("1.2345e-402")) == "1.23e-402"
    assert fmt_sci(Fraction(-99951, 10**405)) == "-1.00e-400"
    assert fmt_sci(10**400) == "1.00e+400" and fmt_sci(Fraction(10**400, 3), 2) == "3.3e+399"
    assert fmt_sci(c.mpf("9.996e-500"), 3) == "1.00e-499"
    assert fmt_sci(1e-5) == "1.00e-05" and fmt_sci(0) == "0" and fmt_sci(c.inf) == "inf"
    import numpy as np

    assert fmt_sci(np.longdouble("1e-4000")) == "1.00e-4000" and fmt_sci(c.mpf("1e-9000")) == "1.00e-9000"
    assert fmt_sci(np.longdouble("-3e4000"), 2) == "-3.0e+4000" and fmt_sci(c.nan) == "nan"


def test_formatting_keeps_sign_and_size_of_every_number_type():
    """A negative mpf beyond a double's range lost its sign (-1e5000 printed "1.00e+5000"); heyoka's real and
    real128 below a double's range printed "0"; fmt_num printed 0 for 1e-400 and raised OverflowError for a
    Fraction of -1e400."""
    from fractions import Fraction

    import heyoka as hy
    import mpmath

    from lieseries.formatting import fmt_num, fmt_sci

    c = mpmath.MPContext()
    c.dps = 50
    assert fmt_sci(c.mpf("-1e5000")) == "-1.00e+5000" and fmt_sci(c.mpf("-2.5e-5000")) == "-2.50e-5000"
    assert fmt_sci(hy.real("1e-400", 1400)) == "1.00e-400" and fmt_sci(hy.real("-2.5e-400", 1400)) == "-2.50e-400"
    assert fmt_sci(hy.real128("1e-4000")) == "1.00e-4000" and fmt_sci(hy.real(0, 100)) == "0"
    assert fmt_sci(hy.real("-inf", 100)) == "-inf" and fmt_sci(hy.real("nan", 100)) == "nan"
    assert fmt_num(c.mpf("1e-400")) == "1e-400" and fmt_num(Fraction(-5 * 10**400, 2)) == "-2.5e+400"
    assert fmt_num(Fraction(1, 3)) == "0.333333" and fmt_num(c.mpf("-1e5000")) == "-1e+5000"


def test_trajectory_plot_draws_errors_below_a_doubles_range(monkeypatch, tmp_path):
    """A 400-digit run's errors (1e-402) are 0.0 as floats: the log axis left its line out and kept its legend
    entry. The axis then shows log10 of the errors, each from its exact value."""
    from types import SimpleNamespace

    import mpmath

    from lieseries.report import scene_report

    c = mpmath.MPContext()
    c.dps = 500
    tr = {"quantity": "q", "names": ["a"], "times": [0.0, 1.0], "values": [[1.0], [2.0]],
          "errors": {"Lie series 400 dps": [c.mpf("1e-402")], "heyoka double": [1e-16]},
          "error_times": {"Lie series 400 dps": [1.0], "heyoka double": [1.0]}}
    figures = []
    monkeypatch.setattr(scene_report, "save_figure", lambda plt, fig, path: figures.append(fig))
    scene_report.plot_trajectory(SimpleNamespace(trajectories={"m": tr}, scene=SimpleNamespace(title="x")),
                                 tmp_path / "x.png")
    drawn = {line.get_label(): list(line.get_ydata()) for line in figures[0].axes[1].get_lines()}
    assert abs(drawn["Lie series 400 dps"][0] + 402) < 1e-9 and abs(drawn["heyoka double"][0] + 16) < 1e-9
    from lieseries.formatting import log10_or_nan

    logs = log10_or_nan([c.mpf("1e-402"), 1e-5, 0, None, c.mpf("1e400")])
    assert abs(logs[0] + 402) < 1e-9 and logs[1] == -5.0 and logs[2] != logs[2] and abs(logs[4] - 400) < 1e-9
