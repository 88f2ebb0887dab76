"""The harness: any backend's RenderResult compared with the reference's, pixel by pixel where
geometry is decided and statistically where a renderer samples, with verdicts.

- backends: the registry of backends by name (the one place that knows which name is the reference),
  rendering any of them without ever raising for a renderer's failure;
- results (verdicts and the result types), geometry (pre-flight, hit masks, ids, t, normals), shading
  (8-bit levels and colour differences), image_only (a backend that gives only an image, a student's
  program: its image compared alone, its geometry SKIP), stochastic (per-pixel Welch tests for sampled images),
  references and attribution (the reference's renders, which rules explain a difference), compare (one
  backend against the reference), run (scenes x backends as jobs, cached), checks (what the command line
  and the API share), junit, judge (a certified oracle's ruling on the reference, the campaign's judge of
  last resort);
- tolerances: every threshold with its derivation, and the way to each backend's own geometry tolerance.

May import: minirt.diagnose, minirt.reference, minirt.oracles and below -- never pages, grading,
campaign, sweep or the CLI.
"""
