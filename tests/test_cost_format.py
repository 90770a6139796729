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
