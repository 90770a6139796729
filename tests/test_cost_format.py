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
