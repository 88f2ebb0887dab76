"""The harness: any backend's RenderResult compared with the reference's, pixel by pixel where
geometry is decided and statistically where a renderer samples, with verdicts.

- backends: the registry of backends by name (the one place that knows which name is the reference),
  rendering any of them without ever raising for a renderer's failure;
- compare: pre-flight, geometry, shading and statistical checks, rule attribution, the check of a scene
  and of many (as jobs), JUnit;
- tolerances: every threshold with its derivation, and the way to each backend's own geometry tolerance.

May import: minirt.diagnose, minirt.reference, minirt.oracles and below -- never pages, grading,
campaign, sweep or the CLI.
"""
