"""Figures and reports: :func:`plot_diagram` draws any :class:`~bifid.continuation.Diagram`,
:class:`Report` writes a self-contained HTML page, :func:`check_report` looks at it in a
headless browser as a user would."""

from bifid.report.html import Report
from bifid.report.plots import plot_curve, plot_diagram, save_figure
from bifid.report.render import check_report, find_chromium

__all__ = ["Report", "check_report", "find_chromium", "plot_curve", "plot_diagram", "save_figure"]
