"""Reports of a reproduction run: Table 4, figures 10-26 and report.md (DESIGN.md §4).

Renders only; the numbers come from :mod:`pkmctl.sim.metrics`::

    from pkmctl.report import draw_figure, make_figures, render_report, table4_csv, table4_markdown
"""

from .document import render_report
from .figures import FIGURES, FigureSpec, draw_figure, figure_names, make_figures
from .tables import PAPER_TABLE4, table4_csv, table4_markdown

__all__ = [
    "FIGURES",
    "PAPER_TABLE4",
    "FigureSpec",
    "draw_figure",
    "figure_names",
    "make_figures",
    "render_report",
    "table4_csv",
    "table4_markdown",
]
