"""Reports: Markdown tables, PNG plots and raw data of a scene run, rendered into a report folder (the package:
``scene_report`` the scene's report, ``stability_report`` the stability report, ``files`` CSV and JSON).

The run and trajectory sections are drawn by ``scene_report``; each study's section, plot and summary line come from the study's
plug-in (:class:`lieseries.studies.Study`), which this module calls with paths in its staging folder.

``write_report(result, out_dir)`` writes::

    out_dir/report.md            title, description, the scene as given, one section per run/study
    out_dir/data.json            everything computed (SceneResult.to_dict())
    out_dir/<table>.csv          one CSV per table
    out_dir/<plot>.png           the plots the scene asks for (trajectory, error_vs_order, work_precision, drift,
                                 departure_map)

``write_stability_report(stability, out_dir)`` writes the stability report (:mod:`lieseries.stability`):
``report.md`` with one row per case, ``data.json``, ``stability.csv``, ``stability_all.csv``, the plots of
:data:`STABILITY_PLOTS` and each case's scene report under ``scenes/<case>/``.

Numbers in the report are the ones computed in that run. Errors are printed in scientific notation with three
significant digits; times in seconds.
"""

from ..formatting import fmt_sci, markdown_table
from ..studies.departure import departure_map_reading, departure_map_table, plot_departure_map
from .scene_report import render_report, report_names, run_tables, section_titles, summary_text, write_report
from .stability_report import STABILITY_PLOTS, stability_tables, write_stability_report

__all__ = ["write_report", "render_report", "write_stability_report", "report_names",
           "markdown_table", "summary_text", "fmt_sci", "SECTION_TITLES", "section_titles",
           "plot_departure_map", "departure_map_table", "departure_map_reading", "run_tables", "stability_tables",
           "STABILITY_PLOTS"]


def __getattr__(name):
    """SECTION_TITLES follows the registry of studies (a study registered later is in it)."""
    if name == "SECTION_TITLES":
        return section_titles()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
