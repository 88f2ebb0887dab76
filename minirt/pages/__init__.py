"""Pages a person reads: the comparison report (report: HTML, its JSON and evidence images), the
contact sheet (sheet: every backend's picture side by side), and the templates they share.

May import: minirt.harness, minirt.diagnose and below.
"""
