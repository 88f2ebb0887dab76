"""What each frame of POV-Ray's animation holds, and how the geometry buffers are encoded into colour
channels and read back (the package docstring's "Buffers" and "Shading": why per-channel frames).

Frames: the colour frame -- or three grey ones, one per channel, when one RGB render cannot express
the materials (:func:`needs_per_channel`) -- then three geometry frames (four from ID_SCALE - 1 shapes
on). A geometry quantity q (x, y, z, t) of shape k is mapped to v = (q - lo)/(hi - lo) over the range
:func:`encoding_ranges` gives shape k, and split into a coarse channel floor(SPLIT v)/SPLIT and a fine
channel frac(SPLIT v), each a half float in POV-Ray's EXR; :func:`decode_geometry` inverts that. The
shape id k + 1 = ID_SCALE hi + lo, each part / ID_SCALE in a channel of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from minirt.model.effects import Effects, effects
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Material, Scene
from minirt.oracles.povray.rays import MAX_DISTANCE, MESH_RAY_ERROR, MIN_ISECT_DEPTH, mesh_reach, pinhole_directions

FAR_ROOT_MARGIN = 10 * MIN_ISECT_DEPTH  # encoding_ranges: a near root this close to the start may be dropped
SPLIT = 1024  # coarse/fine split of an encoded value
ID_SCALE = 2048  # shape id k is (k + 1) = 2048 hi + lo, each part stored as part / 2048: exact in half float
# Error of one decoded value v in [0, 1) in units of 1/SPLIT: the fine channel lies in [0, 1), where a
# half float's spacing is at most 2^-11, so rounding errs by at most 2^-12; POV-Ray's single-precision
# colour arithmetic (colour map, average) adds a few float ulps, bounded generously by 2^-20.
FINE_ERROR = 2.0**-12 + 2.0**-20
HALF_REL = 2.0**-11  # half float: relative rounding error <= 2^-11 (round to nearest, 11-bit significand)
# Channel quantities and parts per geometry frame. The fourth frame only for scenes of ID_SCALE - 1
# shapes or more: below, the id's high part is 0 and the third frame's low part is the whole id.
GEOMETRY_FRAMES = (("x", "x", "y"), ("y", "z", "z"), ("t", "t", "id"), ("id", "", ""))
GEOMETRY_PARTS = (("coarse", "fine", "coarse"), ("fine", "coarse", "fine"), ("coarse", "fine", ""), ("hi", "", ""))


# ---------------------------------------------------------------------------------------------
# What to render


@dataclass(frozen=True)
class Frame:
    """One frame of the animation: a colour render (channel 0-2 for grey per-channel renders, -1 for
    all channels at once) or geometry group 0-3 (see GEOMETRY_FRAMES)."""

    kind: str  # "color" | "geometry"
    index: int

    @property
    def label(self) -> str:
        if self.kind == "color":
            return "color" if self.index < 0 else f"color.{'RGB'[self.index]}"
        return "geometry." + "+".join(
            f"{q}.{p}" if p else q
            for q, p in zip(GEOMETRY_FRAMES[self.index], GEOMETRY_PARTS[self.index], strict=True)
            if q
        )


def is_grey(c: tuple[float, float, float]) -> bool:
    """All three channels equal: a colour POV-Ray's finish can take as one number."""
    return c[0] == c[1] == c[2]


def ambient_numerator(m: Material, scene: Scene, rules: Rules, fx: Effects) -> tuple[float, float, float]:
    """The colour the exercise adds as ambient for material ``m``: its ambient, plus the background where
    the rules add it on a hit (background "on-hit"), each only where the effects simulate it."""
    bg = scene.background if (rules.background == "on-hit" and fx.background) else (0.0, 0.0, 0.0)
    ac = m.ambient if fx.ambient else (0.0, 0.0, 0.0)
    return (ac[0] + bg[0], ac[1] + bg[1], ac[2] + bg[2])


def needs_per_channel(scene: Scene, rules: Rules) -> bool:
    """True when one RGB render cannot express the materials: phong is a scalar (a non-grey specular
    colour), or ambient = pigment * ambient cannot carry a non-zero ambient where the diffuse pigment
    has a zero channel (and the pigment is not grey, i.e. diffuse cannot go into the scalar ``diffuse``)."""
    fx = effects(scene, rules)
    for s in scene.shapes:
        m = s.material
        if fx.specular and not is_grey(m.specular):
            return True
        if fx.diffuse and not is_grey(m.diffuse):
            a = ambient_numerator(m, scene, rules, fx)
            if any(m.diffuse[i] == 0.0 and a[i] != 0.0 for i in range(3)):
                return True
    return False


def color_frames(scene: Scene, rules: Rules) -> list[Frame]:
    if needs_per_channel(scene, rules):
        return [Frame("color", c) for c in range(3)]
    return [Frame("color", -1)]


def geometry_frames(scene: Scene | None = None) -> list[Frame]:
    """The geometry frames: three, and a fourth for the id's high part when the scene has ID_SCALE - 1
    shapes or more (a half float holds an integer part / 2048 exactly only below 2048)."""
    many = scene is not None and len(scene.shapes) >= ID_SCALE - 1
    return [Frame("geometry", g) for g in range(len(GEOMETRY_FRAMES) if many else 3)]


# ---------------------------------------------------------------------------------------------
# Encoding ranges for the geometry buffers, and reading them back


def encoding_ranges(scene: Scene, rules: Rules) -> list[dict[str, tuple[float, float]] | None]:
    """Per shape, the (lo, hi) of x, y, z and t over every hit of POV-Ray's primary rays with that shape
    alone (a ball's near root, and its far root where the near one may not count; t < 1e7), padded by
    1e-4 of the span so rounded hits stay inside [lo, hi).

    A superset of what is visible (occlusion ignored), so every decoded value lies in its range. None
    for a shape no primary ray reaches."""
    d = pinhole_directions(scene, rules)
    cam = np.array(scene.camera.position)
    dist = scene.camera.distance
    # where a ray starts, as a t from the camera: the image plane z = 0 for rule ray_origin "image-plane"
    # (rays with d_z <= 0 never reach it), the camera itself otherwise
    with np.errstate(divide="ignore"):
        t_start = np.where(d[:, 2] > 0, -cam[2] / d[:, 2], np.inf) if rules.ray_origin == "image-plane" else 0.0
    out = []
    for s in scene.shapes:
        ts = []
        if isinstance(s, Ball):
            f = cam - np.array(s.center)
            b = d @ f
            c = f @ f - s.radius**2
            disc = b * b - c
            ok = disc >= 0
            sq = np.sqrt(np.where(ok, disc, 0.0))
            near, far = -b - sq, -b + sq
            ts.append(np.where(ok & (near > 0), near, np.nan))
            # The far root is the visible hit only where the near one is not: before the ray's start, or
            # within POV-Ray's MIN_ISECT_DEPTH of it. FAR_ROOT_MARGIN is ten times that depth plus 1e-6 of
            # the distance, far above the rays' own error there (MESH_RAY_ERROR (R + t) at t ~ 1e-4, and
            # the pinhole's 2^-22 t). Elsewhere the far root cannot be what POV-Ray reports, and leaving it
            # out keeps a huge ball's range (a ground of radius 1e6: its far side 2e6 away) to what is seen.
            maybe = near - t_start < FAR_ROOT_MARGIN + 1e-6 * np.abs(near)
            ts.append(np.where(ok & (far > 0) & maybe, far, np.nan))
        else:
            n = np.array(s.normal)
            nd = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (s.distance - n @ cam) / nd
            ts.append(np.where((nd != 0) & (t > 0), t, np.nan))
        t = np.concatenate(ts)
        dd = np.concatenate([d] * len(ts))
        keep = np.isfinite(t) & (t < MAX_DISTANCE)
        t, dd = t[keep], dd[keep]
        ranges: dict[str, tuple[float, float]] = {}
        if t.size == 0:
            out.append(None)  # no primary ray reaches it: nothing to encode
            continue
        p = cam + t[:, None] * dd
        if rules.ray_origin == "image-plane":  # the exercise's rays start on z = 0: nothing before it is hit
            front = p[:, 2] >= 0
            t, p = t[front], p[front]
            if t.size == 0:
                out.append(None)
                continue
        tq = t * p[:, 2] / (p[:, 2] + dist) if rules.ray_origin == "image-plane" else t
        # A constant coordinate (a plane's y) still gets a span of 1e-6 of the scene's scale, so POV-Ray's
        # rounding of far hits (~1e-16 of |P|) stays far inside the padding.
        scale = max(1.0, float(np.abs(p).max()), float(t.max()))
        # POV-Ray's own rays hit up to MESH_RAY_ERROR (R + t) from these (the pinhole's error is smaller):
        # the ranges hold that too, now that a ball's far side no longer widens them.
        ray = MESH_RAY_ERROR * (mesh_reach(scene, rules) + float(t.max()))
        for name, q in (("x", p[:, 0]), ("y", p[:, 1]), ("z", p[:, 2]), ("t", tq)):
            lo, hi = float(q.min()), float(q.max())
            span = max(hi - lo, 1e-6 * scale)
            ranges[name] = (lo - 1e-4 * span - ray, hi + 1e-4 * span + ray)
        out.append(ranges)
    return out


def decode_geometry(
    scene: Scene, rules: Rules, imgs: list[np.ndarray], ranges: list[dict[str, tuple[float, float]]]
) -> dict[str, Any]:
    """Buffers from the geometry frames (RGBA half floats; three, or four with the id's high part)."""
    h, w = imgs[0].shape[:2]
    ch: dict[tuple[str, str], np.ndarray] = {}
    for g, img in enumerate(imgs):
        for c, (q, part) in enumerate(zip(GEOMETRY_FRAMES[g], GEOMETRY_PARTS[g], strict=True)):
            ch[(q, part)] = img[..., c].astype(np.float64)
    alphas = [img[..., 3] > 0.5 for img in imgs]
    hit = alphas[0]
    hi = np.rint(ch[("id", "hi")] * ID_SCALE) if ("id", "hi") in ch else 0.0
    sid = (np.rint(ch[("id", "")] * ID_SCALE) + ID_SCALE * hi).astype(np.int32) - 1
    mismatch = int(sum(np.count_nonzero(a != hit) for a in alphas[1:]) + np.count_nonzero((sid >= 0) != hit))
    sid = np.where(hit, sid, -1)
    pos = np.zeros((h, w, 3))
    t = np.full((h, w), np.inf)
    nrm = np.zeros((h, w, 3))
    residual: dict[str, float] = {}  # self-check: distance of decoded points from their surface
    for k, s in enumerate(scene.shapes):
        m = sid == k
        if not m.any():
            continue
        vals = {}
        for q in ("x", "y", "z", "t"):
            lo, hi = ranges[k][q] if ranges[k] is not None else (0.0, 1.0)
            v1024 = np.rint(ch[(q, "coarse")][m] * SPLIT) + ch[(q, "fine")][m]
            vals[q] = lo + v1024 * ((hi - lo) / SPLIT)
        p = np.stack([vals["x"], vals["y"], vals["z"]], axis=-1)
        pos[m] = p
        t[m] = vals["t"]
        if isinstance(s, Ball):
            nrm[m] = (p - np.array(s.center)) / s.radius
            residual[str(k)] = float(np.abs(np.linalg.norm(p - np.array(s.center), axis=-1) - s.radius).max())
        else:
            nrm[m] = np.array(s.normal)
            residual[str(k)] = float(np.abs(p @ np.array(s.normal) - s.distance).max())
    return {"hit": hit, "shape_id": sid, "t": t, "position": pos, "normal": nrm, "hit_mismatch": mismatch,
            "surface_residual": residual}  # fmt: skip
