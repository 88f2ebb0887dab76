"""The reference tracer: the exercise's model (problem 13.1) evaluated with Dr.Jit, every rule
switchable, and the tools built on it.

- tracer: the Tracer façade and render(), split along the seams of pbrt's design: values (the scene's
  values, unrolled into the kernel or gathered from tables, behind one protocol), shapes (Ball and Plane
  intersection), interaction (hit point, normal, error bound, offsets), shading (the terms and shadow
  rays), integrator (levels, reflection, combining), sampling (primary and supersampled rays) and film
  (buffers and tiles); the parts read only settings (``TraceSettings``: the scene, rules, types, values,
  effects), never the façade;
- accel: the shape table and the ball BVH; band: how close each primary ray is to a decision rounding
  can flip (the silhouette and start bands); hazards: what in a scene makes its image depend on scale
  or precision, said as warnings; probe: one pixel, traced step by step by the tracer itself; backend:
  the tracer behind the Backend interface.

May import: minirt.model, minirt.jit and below -- not files or jobs (the tracer stands on the model
alone), never the oracles, the harness, the pages or the CLI.
"""
