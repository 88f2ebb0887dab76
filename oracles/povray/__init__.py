"""POV-Ray 3.7 as an oracle: the exercise's scene exported to POV-Ray's scene language, rendered, read back.

Conventions bridged (each measured with Debian's povray 3.7.0.10):

- Frame: POV-Ray is left-handed, x right, y up, camera looking along +z -- the exercise's own frame, so
  coordinates are written as they are (nothing mirrored).
- Pixel corner: with antialiasing off POV-Ray shoots pixel (i, j) through its CENTRE,
  normalise(D + x0 R + y0 U) with x0 = (i+0.5)/W - 0.5, y0 = 0.5 - (j+0.5)/H. A skewed
  ``direction <-0.5/W, 0.5/H, d>`` with ``right <1,0,0>``, ``up <0,1,0>``, ``location <0,0,-d>`` shifts
  that by half a pixel onto the exercise's CORNER rays (rule pixel_sample "corner"); for "center" the
  plain ``direction <0,0,d>``. No look_at/angle (they make the parser rewrite the vectors).
- Ray start: POV-Ray's primary rays start at the camera, the exercise's on the image plane z = 0 (rule
  ray_origin "image-plane"). The two agree unless a shape reaches into the pyramid between the camera
  and the image plane. Only then (simulate only what the scene calls for) the camera is a
  ``mesh_camera`` (distribution 0: pixel k's ray starts at the centroid of triangle k and runs along its
  face normal): one triangle per pixel, centred on the exercise's ray origin on z = 0, perpendicular
  to its direction. POV-Ray gives image row j the triangles of row j - 1, so H + 1 rows are rendered
  and the first dropped (measured: with it the hit mask and ids equal the reference's). Mesh vertices
  and normals are single precision: origins err by ~2^-24 |P|, directions by ~2^-23, which adds
  2^-22 (1 + t) to positions (``precision``) and a relative margin to the band, per shape
  (``band_scales``: each ball's own distance; ``band_inside_scales`` adds the bounding boxes;
  ``band_threshold`` is the largest).
  Antialiasing cannot be combined with it (the mesh camera maps a pixel to one triangle). t is
  re-based on the image-plane origin: t = |P - cam| * z / (z + d) (the part of the camera ray before
  z = 0 removed; with the mesh camera the same line starts at z = 0, so the same formula).
- Normals: POV-Ray flips them to face the viewer (two_sided True) and skips a light entirely when
  n·l < 1e-10 (no diffuse, no phong; phong only when r·l > 0): clamp True. Balls are seen from inside
  (near_root_only False).
- Shadows: only objects with 1e-3 < t < distance_to_light - 1e-3 block; objects beyond the light never
  shadow (shadow_range "to-light"). Secondary rays use POV-Ray's own epsilons (1e-3 for shadow rays);
  the closest exercise rule is offset "error-bound".
- Depth: ``max_trace_level`` N = primary ray plus N-1 bounces, so N = max_depth + 1; ``adc_bailout 0``
  (the default 1/255 prunes faint reflections).
- Shading: POV-Ray multiplies ambient by the pigment, so a material (ambient AC, diffuse DC, specular
  SC, reflection RC) becomes ``pigment { rgb DC } finish { ambient rgb (AC+BG)/DC diffuse 1 phong SC
  phong_size E reflection { rgb RC } }`` (E the rule specular_exponent, 8 by default) -- or, exactly and
  without a division, ``pigment { rgb 1 }`` with ``diffuse DC`` when DC is grey. BG is folded into
  ambient for rule background "on-hit"; for "on-miss" it is a ``background``; for "none" neither.
  ``phong`` is a scalar: when a specular colour is not grey, or a non-grey diffuse colour has a zero
  channel under a non-zero ambient, the scene is rendered once per colour channel with grey values and
  the channels combined.
- Output: ``assumed_gamma 1.0`` and File_Gamma 1.0 (linear values). The 8-bit PNG (+FN8) rounds
  floor(c*255 + 0.5) exactly as the exercise does; the float colour is POV-Ray's EXR, which is HALF
  float only (relative precision 2^-11; its own rounding flips 8-bit levels at .5 ties, hence both).
- Buffers (one EXR animation, frame_number selects the pass, to pay POV-Ray's ~0.65 s start-up once):
  hit mask from the alpha channel (+UA, no background); shape id from a constant pigment per shape
  (``finish { ambient 1 diffuse 0 }``), k + 1 = 2048 hi + lo with each part / 2048 in a channel of its
  own (a half float holds j / 2048 exactly for j < 2048; the hi frame only from 2,047 shapes: one id
  channel read (k + 1) / 2048 clamped to 1, and a scene of 10,000 balls "failed" 12,736 of 16,384 ids);
  position and t from pigment functions, each quantity q mapped to
  v = (q - lo)/(hi - lo) with a per-shape range and split into a coarse channel floor(1024 v)/1024 and a
  fine channel frac(1024 v) (decode v = coarse + fine/1024); normals analytically per shape from the
  decoded position ((P - C)/r, or the plane's normal, unflipped like the reference's).
- Antialiasing (``options={"antialias": R}``, R in 1..9): ``+A0.0 +R{R}`` instead of ``-A``. Threshold 0
  supersamples every pixel on POV-Ray's own jittered sub-pixel grid (method 1, default jitter, which is
  deterministic), not the exercise's stratified pattern. Colour only: no geometry frames and no 8-bit PNG
  pass (one start-up per render), ``image8`` is None. The supersampled area is POV-Ray's pixel square,
  which the "corner" skew shifts by half a pixel; to compare with the reference's samples (which cover
  [x, x+1) x [y, y+1)) render both with rule pixel_sample "center". Without the option: one ray per pixel.
- The exercise's own samples (``options={"samples": n}``, n > 1): a mesh_camera with n meshes, mesh s
  holding sample s's rays (camera.sample_offsets, the reference's stratified pattern), one triangle
  per pixel; POV-Ray shoots ray s of each pixel from mesh s and averages the n colours (distribution 0,
  ``rays_per_pixel`` n). So its image is the reference's n-sample image, pixel by pixel, up to its
  single-precision colour and the mesh's single-precision rays. Colour only (no geometry frames); the
  8-bit PNG pass is kept. At most MAX_MESH_RAYS = n x W x H rays (scene text ~130 bytes each, parsed once
  per pass); excludes ``antialias``.
- Numeric limits: hits beyond 1e7 and nearer than 1e-4 to the ray's origin are dropped (the
  latter matters for the mesh camera's image-plane origins: meta precision ``min_distance`` and
  ``start_err``, start_decision(), give the band of minirt.reference.band.start_band); an exactly tangent
  ray misses a sphere; |n·d| < 1e-10 misses a plane; with 3 or more finite objects POV-Ray builds
  float bounding boxes; coincident surfaces: the first declared object wins.
- Untrusted input: POV-Ray's language can open, read and write files. The exporter writes only numbers
  (Python floats, checked finite) and fixed keywords: no scene, material or file name ever reaches a
  .pov file.

The package, one job a file (each opens with its parameters and conventions):

- ``rays.py``: POV-Ray's rays against the exercise's -- which camera, how far off, which hits dropped;
- ``buffers.py``: what each frame holds; the geometry encoded into colour channels, and decoded;
- ``exporter.py``: the scene language writer (numbers and fixed keywords only), ``minirt export``;
- ``runner.py``: the command line, the process, its files, errors, timings and version;
- ``accuracy.py``: what the decoded numbers and POV-Ray's own arithmetic are worth (meta["precision"]);
- ``oracle.py``: PovrayOracle, which puts them together, and its geometry tolerance.
"""

from __future__ import annotations

from minirt.oracles.povray.accuracy import (
    band_inside_scales,
    band_origin_scales,
    band_scales,
    band_threshold,
    origin_lift,
    precision,
    root_errors,
    start_decision,
)
from minirt.oracles.povray.buffers import (
    Frame,
    color_frames,
    decode_geometry,
    encoding_ranges,
    geometry_frames,
    needs_per_channel,
)
from minirt.oracles.povray.exporter import MESH_NAME, export, scene_to_pov
from minirt.oracles.povray.oracle import PovrayOracle
from minirt.oracles.povray.rays import (
    MAX_DISTANCE,
    MAX_MESH_RAYS,
    MESH_RAY_ERROR,
    MIN_ISECT_DEPTH,
    between_camera_and_image_plane,
    mesh_reach,
    too_many_mesh_rays,
    uses_mesh_camera,
)
from minirt.oracles.povray.runner import INSTALL_HINT, NAME, PovrayError, command, default_timeout
from minirt.oracles.povray.runner import run_povray as run_povray  # benchmarks/bench.py times one pass with it

__all__ = [
    "INSTALL_HINT",
    "MAX_DISTANCE",
    "MAX_MESH_RAYS",
    "MESH_NAME",
    "MESH_RAY_ERROR",
    "MIN_ISECT_DEPTH",
    "NAME",
    "Frame",
    "PovrayError",
    "PovrayOracle",
    "band_inside_scales",
    "band_origin_scales",
    "band_scales",
    "band_threshold",
    "between_camera_and_image_plane",
    "color_frames",
    "command",
    "decode_geometry",
    "default_timeout",
    "encoding_ranges",
    "export",
    "geometry_frames",
    "mesh_reach",
    "needs_per_channel",
    "origin_lift",
    "precision",
    "root_errors",
    "scene_to_pov",
    "start_decision",
    "too_many_mesh_rays",
    "uses_mesh_camera",
]
