"""A study as a plug-in, in one file: every invariant of each model at t = 0 and at the end of one heyoka run.

``[studies.energy_table]`` with ``t`` (the final time) and ``precision``; the report gets an "Energy table"
section (a table and a CSV) and, when ``report.plots`` names it, a bar chart of |I(t) - I(0)|.
"""

from dataclasses import dataclass

import lieseries as ls
from lieseries import fields as F
from lieseries.formatting import fmt_sci, markdown_table, pyplot, save_figure
from lieseries.studies import Study, register_study
from lieseries.studies.drift import invariant_function


@dataclass
class EnergyTable:
    t: float
    status: str
    initial: dict
    final: dict

    def to_dict(self):
        return {"t": self.t, "status": self.status, "initial": self.initial, "final": self.final}


class EnergyTableStudy(Study):
    name = "energy_table"
    title = "Energy table"
    fields = {"t": (F.positive, F.REQUIRED), "precision": (F.precision, "double")}
    docs = {"t": ("positive number", "the final time"), "precision": ("precision", "heyoka's precision")}
    quick_doc = "half the time"

    def quick(self, opts):
        opts["t"] = float(opts["t"]) / 2

    def run(self, opts, ctx):
        out = []
        for lab, model in ctx.built:
            y0 = ctx.initial_state(model)
            sol = ls.integrate(model, y0, t=opts["t"], precision=opts["precision"])
            inv = invariant_function(model, 40)
            out.append((lab, EnergyTable(float(sol.t[-1]), sol.status, {k: float(v) for k, v in inv(y0).items()},
                                         {k: float(v) for k, v in inv(sol.y[-1]).items()})))
        return out

    def unsuccessful(self, items):
        return [f"energy table ({lab}): {et.status}" for lab, et in items if et.status != "success"]

    def section(self, items, ctx):
        h = ["model", "invariant", "I(0)", "I(t)", "|I(t) - I(0)|"]
        rows = [[lab, k, fmt_sci(v, 17), fmt_sci(et.final[k], 17), fmt_sci(abs(et.final[k] - v))]
                for lab, et in items for k, v in et.initial.items()]
        lines = ["Each invariant at t = 0 and at the end of one run.", "", markdown_table(h, rows), ""]
        if ctx.plotted:
            lines += ["![energy table](energy_table.png)", ""]
        return lines, [("energy_table.csv", h, rows)]

    def plot(self, items, path, scene):
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(5, 3))
        names = [f"{lab}: {k}" for lab, et in items for k in et.initial]
        ax.bar(names, [max(abs(et.final[k] - v), 1e-300) for _, et in items for k, v in et.initial.items()])
        ax.set_yscale("log")
        save_figure(plt, fig, path)

    def summary(self, items):
        return [f"energy table ({lab}): {len(et.initial)} invariants to t = {et.t:g}" for lab, et in items]


register_study(EnergyTableStudy())
