"""The exercise's model, and what every backend shares: no renderer, no harness, no pages here.

- scene: the scene format (TOML, validated by pydantic) and the model: Ball, Plane, Material, Camera,
  Light, Scene; bundled: the scenes shipped with minirt, found by name.
- rules: where the pseudo-code and established renderers disagree, each a named rule, grouped in
  profiles; effects: what a scene under its rules calls for (only those are simulated).
- camera: the exercise's primary rays, shared by the tracer and every oracle; bitmap: the exercise's
  8-bit output encoding.
- result: RenderResult, the one type every backend returns; backend: the interface every backend
  implements (the reference and each oracle); tolerance: the geometry tolerance a backend declares
  from the harness's measured margins; series: a backend's accuracy knob as the sweep turns it.
- bundled.scene_and_rules: the one way a scene is made ready to render (read, overrides, rules).

May import: minirt.errors, minirt.version, and nothing else of minirt.
"""
