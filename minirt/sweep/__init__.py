"""What accuracy costs in time: turn each backend's accuracy knobs, measure time and error on one scene.

For every backend the sweep renders the same scene (square, ``size`` x ``size``) at each setting of
each of its knobs, times it, and measures the error against that series' *converged* answer. What a
backend sweeps -- its knobs and their settings, the rules it renders under, the converged answer, the
kind of error, the cost axis, what theory expects, how its time is read -- is the backend's own
(``Backend.sweep`` in minirt.model.backend; minirt.reference.backend and each oracle say theirs, with
the reasons); the sweep names no backend.

One module per concern:

- minirt.sweep.series: every backend's series (``catalogue``), the errors they are measured by, the
  criteria of the answer;
- minirt.sweep.timing: the warm-up, the timed runs and their median;
- minirt.sweep.run: the series as jobs (here, in local processes or on a cluster; cached), the rows, and
  sweep.json's document (``run_sweep``);
- minirt.sweep.document: fits, the Pareto front, the answer, and the files (CSV, Markdown, JSON);
- minirt.sweep.plots: the log-log plots.

API: :func:`minirt.sweep.run.run_sweep` writes ``sweep.csv``, ``sweep.md``, ``sweep.json``, one
``sweep-<backend>.png`` per backend and ``sweep.png`` (all series) into ``out_dir`` and returns the JSON
dict. The settings swept are each backend's defaults (``Backend.sweep_knobs``), overridable per call
through ``knobs``, per backend by knob name. A backend that is missing (or fails at a setting) gives rows
with status "skip" or "error" and the reason; nothing raises.

May import: minirt.pages, minirt.harness and below.
"""
