"""The ray route (``mode = "rays"``, the default): the exact rays of minirt.model.camera.primary_rays,
rounded to Mitsuba's float32, traced with ``scene.ray_intersect``; shading is a loop of stock calls --
``sample_emitter_direction`` with its visibility test (the shadow ray), ``bsdf.eval`` of the shape's
BSDF, and ``conductor.sample`` to follow delta reflections only, up to ``max_depth``.

Its conventions (package docstring): intensity I = lc, so the diffuse term is Mitsuba's own and
aux["diffuse_to_exercise"] = pi r^2 converts it per pixel; shadows on planes skip a rectangle's hit on
itself (its float32 slab); the rectangles grow after tracing until every point a traced ray could hit
is covered (at most _MAX_RESIZE times). With a scalar variant every batch is a loop over single rays.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from minirt.jit.arrays import aligned
from minirt.model import camera
from minirt.model.result import RenderResult, geometry_from_flat, to8
from minirt.model.scene import Plane
from minirt.oracles.mitsuba.accuracy import silhouette_t_bound
from minirt.oracles.mitsuba.planes import PlaneRect, plane_frames, plane_hits
from minirt.oracles.mitsuba.render import MitsubaRender
from minirt.oracles.mitsuba.variants import BACKEND

# Growths of the plane rectangles before giving up. Each growth can uncover more: a reflection that now
# hits a grown rectangle far away, whose shadow segment crosses another plane outside its rectangle (a
# fuzzed scene with two far-reaching planes and four bounces needed 4). The last growth is always
# rendered; if growth still goes on after this many, meta["plane_coverage_complete"] is False.
_MAX_RESIZE = 8


class RayRender(MitsubaRender):
    """The harness's rays through Mitsuba's intersector and a loop of stock shading calls."""

    def run(self) -> RenderResult:
        sc, rules = self.scene, self.rules
        w, h = sc.camera.width, sc.camera.height
        o64, d64 = camera.primary_rays(sc, rules)
        # Mitsuba sees the rays in float32: every float64 check below uses the same rounded rays.
        o32, d32 = o64.astype(np.float32).astype(np.float64), d64.astype(np.float32).astype(np.float64)
        rects = plane_frames(sc, o32, d32)
        mats = [s.material for s in sc.shapes]
        lit = any(v != 0 for v in sc.light.color) and any(any(v != 0 for v in m.diffuse) for m in mats)
        reflective = [k for k, m in enumerate(mats) if any(v != 0 for v in m.reflection)]
        depth = sc.max_depth if reflective else 0
        resizes = 0
        t_render = 0.0
        while True:
            ms = self.load(rects)
            self.passes = ["intersect(primary)"]
            t0 = time.perf_counter()
            levels = self.trace(ms, o32, d32, lit, reflective, depth)
            t_render += time.perf_counter() - t0
            rendered = {f"shape{k}": r_.describe() for k, r_ in rects.items()}  # before coverage grows them
            grew = self.check_coverage(rects, levels)
            if not grew or resizes >= _MAX_RESIZE:
                break
            resizes += 1
        self.timings["render"] = t_render
        lvl0 = levels[0]
        geom = geometry_from_flat(w, h, lvl0["sid"], lvl0["t"], lvl0["p"], lvl0["n"])
        # back to front: c = local + kr * c_child (Mitsuba units) and the same in exercise units
        child = child_x = None
        for lvl in reversed(levels):
            c, cx = lvl["local"].copy(), lvl["local_x"].copy()
            lvl["refl"] = np.zeros_like(c)
            lvl["refl_x"] = np.zeros_like(c)
            if child is not None:
                lvl["refl"][lvl["child_idx"]] = lvl["kr"][lvl["child_idx"]] * child
                lvl["refl_x"][lvl["child_idx"]] = lvl["kr"][lvl["child_idx"]] * child_x
                c, cx = c + lvl["refl"], cx + lvl["refl_x"]
            child, child_x = c, cx
        color = child.reshape(h, w, 3)
        terms = {"diffuse": lvl0["local"].reshape(h, w, 3), "reflection": lvl0["refl"].reshape(h, w, 3)}
        r = np.where(geom["hit"], lvl0["dist"].reshape(h, w), 0.0)
        aux = {
            "t_silhouette_bound": silhouette_t_bound(sc, o32, d32, geom["shape_id"].ravel()).reshape(h, w),
            "light_distance": r,
            "diffuse_to_exercise": math.pi * r * r,
            "diffuse_exercise": lvl0["local_x"].reshape(h, w, 3),
            "reflection_exercise": lvl0["refl_x"].reshape(h, w, 3),
        }
        extra = {
            "planes": rendered,  # the rectangles this render used
            "plane_resizes": resizes,
            # False: the rectangles still missed points a traced ray could hit after _MAX_RESIZE growths
            "plane_coverage_complete": not grew,
            # shadow segments whose first hit was their own rectangle, restarted past its float32 slab
            "shadow_self_hits": self.self_hit_segments,
            "image8_shows": "diffuse + reflection only, x pi r^2",
            "parameters": {"reflection_depth": depth, "shading": "diffuse" if lit else "none",
                           "reflective_shapes": reflective},
            "aux": {
                "t_silhouette_bound": "the margin-dependent part of the t error bound on balls (silhouette_t_bound)",
                "light_distance": "Mitsuba's emitter distance r at each primary hit (0 on a miss)",
                "diffuse_to_exercise": "pi r^2: terms.diffuse * pi r^2 = n.s dc lc (emitter.intensity = lc, so "
                "terms.diffuse * pi r^2 / intensity = n.s dc)",
                "diffuse_exercise": "terms.diffuse * pi r^2: the exercise's diffuse term",
                "reflection_exercise": "terms.reflection with the same correction applied at every bounce",
            },
        }  # fmt: skip
        image8 = to8(aux["diffuse_exercise"] + aux["reflection_exercise"])  # display only: see the docstring
        return RenderResult(
            backend=BACKEND, width=w, height=h, color=color, terms=terms, aux=aux, image8=image8,
            meta=self.meta("rays", extra), **geom,
        )  # fmt: skip

    # -- coverage of the rectangles -------------------------------------------------------------
    def check_coverage(self, rects: dict[int, PlaneRect], levels: list[dict[str, Any]]) -> bool:
        """Grow rectangles to every plane point a traced ray could have hit; True if any grew."""
        light = np.asarray(self.scene.light.position, dtype=np.float64)
        grew = False
        for k, r in rects.items():
            for lvl in levels:
                o, d, t_mi = lvl["o"], lvl["d"], lvl["t"]
                t = plane_hits(r, o, d)
                # the infinite plane would be the nearest hit, but Mitsuba reported nothing that near
                miss = np.isfinite(t) & (lvl["sid"] != k) & (t < t_mi * (1 - 1e-4))
                p = o[miss] + t[miss, None] * d[miss]
                if len(p) and np.any(r.outside(p)):
                    grew |= r.include(p)
                if lvl.get("shadow") is not None:
                    so = lvl["shadow"]
                    sd = light - so
                    ts = plane_hits(r, so, sd)  # segment parameter in (0, 1) crosses the plane
                    cross = ts < 1
                    p = so[cross] + ts[cross, None] * sd[cross]
                    if len(p) and np.any(r.outside(p)):
                        grew |= r.include(p)
        return grew

    # -- one batch of rays per level ------------------------------------------------------------
    def trace(self, ms, o, d, lit: bool, reflective: list[int], depth: int) -> list[dict[str, Any]]:
        levels = []
        idx = None
        for level in range(depth + 1):
            if level > 0:
                self.passes.append(f"intersect(reflection {level})")
            lvl = self.shade(ms, o, d, lit, reflective if level < depth else [], level)
            lvl["parent"] = idx
            levels.append(lvl)
            if level < depth:
                spawn = lvl.get("spawn")
                if spawn is None or not np.any(spawn):
                    break
                ci = np.nonzero(spawn)[0]
                lvl["child_idx"] = ci
                o, d = lvl["next_o"][ci], lvl["next_d"][ci]
                idx = ci
        return levels

    def shade(self, ms, o, d, lit: bool, reflective: list[int], level: int) -> dict[str, Any]:
        if self.jit:
            return self._shade_batch(ms, o, d, lit, reflective, level)
        parts = [self._shade_batch(ms, o[i : i + 1], d[i : i + 1], lit, reflective, level) for i in range(len(o))]
        out: dict[str, Any] = {}
        for key in parts[0] if parts else []:
            vals = [p[key] for p in parts]
            out[key] = None if vals[0] is None else np.concatenate(vals)
        return out

    def _np(self, x) -> np.ndarray:
        return np.atleast_1d(np.asarray(x, dtype=np.float64))

    def _eval(self, *values) -> None:
        """Evaluate what is read next in one kernel (JIT variants): each read-back of an unevaluated
        quantity is a kernel of its own, about 10 ms to assemble with Mitsuba's virtual calls in it -- 228
        of them made 5 s of a 1,024-ball render at 128². The same values either way."""
        if self.jit:
            self._dr().eval(*values)

    def _np3(self, v) -> np.ndarray:
        return np.stack([self._np(v[i]) for i in range(3)], axis=1)

    def _f32(self, a: np.ndarray) -> Any:
        """Host values as Mitsuba's float: the one value of a one-ray batch in scalar mode, else an array
        at a 64-byte boundary (minirt.jit.arrays: so the same kernels are not compiled again)."""
        return float(a[0]) if not self.jit else self.mi.Float(aligned(a, np.float32))

    def _ray(self, o: np.ndarray, d: np.ndarray) -> Any:
        """Mitsuba rays from (N, 3) origins and directions."""
        f32, mi = self._f32, self.mi
        return mi.Ray3f(
            o=mi.Point3f(*(f32(o[:, i]) for i in range(3))), d=mi.Vector3f(*(f32(d[:, i]) for i in range(3)))
        )

    def _shade_batch(self, ms, o, d, lit: bool, reflective: list[int], level: int) -> dict[str, Any]:
        mi = self.mi
        n = len(o)
        scalar = not self.jit
        ray = self._ray(o, d)
        si = ms.ray_intersect(ray)
        valid = si.is_valid()
        if self.jit:
            self._eval(si.t, si.p, si.n, valid, self._dr().reinterpret_array(mi.UInt32, si.shape))
        hit, sid = self._hits(ms, si, n)
        out: dict[str, Any] = {
            "o": o, "d": d, "sid": sid,
            "t": np.where(hit, self._np(si.t), np.inf),
            "p": np.where(hit[:, None], self._np3(si.p), 0.0),
            "n": np.where(hit[:, None], self._np3(si.n), 0.0),
            "local": np.zeros((n, 3)), "local_x": np.zeros((n, 3)), "dist": np.zeros(n),
            "kr": np.zeros((n, 3)), "shadow": None,
        }  # fmt: skip
        if scalar and not hit[0]:
            return out  # scalar variants: si.bsdf() of a miss is a null pointer (eval would crash)
        if lit:
            self._light(ms, si, ray, valid, sid, hit, n, level, out)
        if reflective:
            self._reflect(si, sid, reflective, n, level, out)
        return out

    def _light(self, ms, si, ray, valid, sid, hit, n: int, level: int, out: dict[str, Any]) -> None:
        """The lit rays' local colour (Mitsuba's emitter sample and BSDF, shadowed by its own visibility
        test) into ``out``: local, dist, local_x, shadow."""
        mi = self.mi
        if f"emitter+visibility(level {level})" not in self.passes:
            self.passes += [f"emitter+visibility(level {level})", f"bsdf.eval(level {level})"]
        ctx = mi.BSDFContext()
        planes = [k for k, sh in enumerate(self.scene.shapes) if isinstance(sh, Plane)]
        # With planes, the visibility test is Mitsuba's own ray_intersect on the shadow segment
        # (spawn_ray_to: Mitsuba's offsets, stops short of the light), except that a plane's hit on
        # itself does not count: an infinite plane never shadows its own points, but the
        # rectangle standing in for it can, through its float32 corners (abs_error in meta planes;
        # a fuzzed scene's 77,000-unit rectangle shadowed 458 of its own pixels).
        ds, em_w = ms.sample_emitter_direction(si, mi.Point2f(0.5, 0.5), not planes, valid)
        bsdf = si.bsdf(ray)
        f = bsdf.eval(ctx, si, si.to_local(ds.d), valid)
        fe = f * em_w
        self._eval(fe, ds.dist, ds.p)
        local = self._np3(fe)
        if planes:
            # Only whether and what the segment hits: Mitsuba's preliminary intersection, the same hit and
            # shape as ray_intersect without its surface interaction -- a virtual call over every shape,
            # recorded again each time (10,000 balls: about a second a call).
            s2 = ms.ray_intersect_preliminary(si.spawn_ray_to(ds.p))
            hit2, sid2 = self._hits(ms, s2, n, hit)
            own = np.isin(sid, planes) & (sid2 == sid)

            blocked = hit2 & ~own
            if own.any():  # past the rectangle's hit on itself, the rest of the segment still counts
                blocked |= own & self._past_own_plane(ms, si, ds, sid, own, n, hit)

            local = np.where(blocked[:, None], 0.0, local)
        dist = self._np(ds.dist)
        local = np.where(hit[:, None], local, 0.0)
        out["local"] = local
        out["dist"] = np.where(hit, dist, 0.0)
        # intensity I = lc, so local * pi r^2 = dc lc max(0, n.s): the exercise's diffuse term
        out["local_x"] = np.where(hit[:, None], local * (math.pi * dist * dist)[:, None], 0.0)
        out["shadow"] = out["p"][hit]  # shadow segments start (about) here; coverage check only

    def _reflect(self, si, sid, reflective: list[int], n: int, level: int, out: dict[str, Any]) -> None:
        """The reflected rays of the hits on reflective shapes, from Mitsuba's conductor, into ``out``: kr,
        spawn, next_o, next_d."""
        mi = self.mi
        scalar = not self.jit
        self.passes.append(f"conductor.sample(level {level})")
        spawn = np.zeros(n, dtype=bool)
        next_o, next_d = np.zeros((n, 3)), np.zeros((n, 3))
        ctx = mi.BSDFContext()
        # One conductor per reflection colour, sampled for every ray that hit a shape of that colour:
        # shapes with the same colour have the same BSDF, and a lane's sample depends on its own ray
        # alone, so the same numbers as a call per shape -- whose masked batch calls (kernels, read-backs)
        # made a 1,024-ball check at 128x128 take 9 minutes in this loop.
        by_colour: dict[tuple[float, ...], list[int]] = {}
        for k in reflective:
            by_colour.setdefault(tuple(self.scene.shapes[k].material.reflection), []).append(k)
        for kr, shapes in by_colour.items():
            mask_np = np.isin(sid, shapes)
            if not mask_np.any():
                continue
            cond = self.conductor(kr)
            mask = mi.Bool(bool(mask_np[0])) if scalar else mi.Bool(mask_np)
            bs, weight = cond.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5), mask)
            nray = si.spawn_ray(si.to_world(bs.wo))
            self._eval(weight, nray.o, nray.d, bs.pdf)
            ok = mask_np & self._np(mask & (bs.pdf > 0)).astype(bool)
            out["kr"][ok] = self._np3(weight)[ok]
            next_o[ok], next_d[ok] = self._np3(nray.o)[ok], self._np3(nray.d)[ok]
            spawn |= ok & np.any(out["kr"] != 0, axis=1)
        out.update(spawn=spawn, next_o=next_o, next_d=next_d)

    def _past_own_plane(self, ms, si, ds, sid, own, n: int, hit) -> np.ndarray:
        """Whether the shadow segments ``own`` (whose first hit was the rectangle of the plane their point
        lies on) are blocked beyond that rectangle's float32 slab.

        The rectangle lies within abs_error of the plane (meta planes), so a segment leaving a point on it
        in direction s is within that slab for 2 abs_error / |n·s| of its length: every hit on the
        rectangle there is a self-hit. Restarting at the self-hit (Mitsuba's spawn_ray_to, an offset of
        ~1e-4 at these scales) lands inside the slab again and again on a huge rectangle (a fuzzed scene:
        abs_error 2.7e-3, 24 shadows lost behind another plane); so the segment restarts past the slab. An
        occluder within that stretch is within the oracle's own position error of the point (the harness
        does not judge those: shadow_margin)."""
        p, sd, seg = self._np3(si.p), self._np3(ds.d), self._np(ds.dist)
        skip = np.zeros(n)
        for k, err in self.plane_abs.items():
            on = own & (sid == k)
            if on.any():
                nd = np.abs(sd[on] @ np.asarray(self.scene.shapes[k].normal))
                skip[on] = 2 * err / np.maximum(nd, 1e-12)
        go = own & (skip < seg)
        self.self_hit_segments += int(own.sum())
        o2 = p + skip[:, None] * sd
        maxt = np.where(go, (seg - skip) * (1 - 1e-4), 0.0)  # stops short of the light, as spawn_ray_to does

        ray = self._ray(o2, sd)
        ray.maxt = self._f32(maxt)
        hit3, sid3 = self._hits(ms, ms.ray_intersect_preliminary(ray), n, hit)
        return go & hit3 & (sid3 != sid)

    def _hits(self, ms, si, n: int, among: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Which of n rays hit (within ``among``), and the scene index of the shape each hit (``si``: a
        surface interaction or a preliminary intersection)."""
        mi, dr = self.mi, self._dr()
        hit = self._np(si.is_valid()).astype(bool)
        if among is not None:
            hit = hit & among
        reg = self._np(dr.reinterpret_array(mi.UInt32, si.shape) if self.jit else 0).astype(np.int64)
        if not self.jit:
            reg = np.array([self._scalar_index(ms, si) if hit[0] else -1])
        return hit, self.map_ids(np.broadcast_to(reg, (n,)), hit)

    def _scalar_index(self, ms, si) -> int:
        for i, s in enumerate(ms.shapes()):
            if s == si.shape:
                return i
        return -1

    def conductor(self, kr: tuple[float, ...]):
        """A perfect mirror (Mitsuba's ``conductor``, two-sided) of reflection colour kr."""
        cache = self.__dict__.setdefault("_conductors", {})
        if kr not in cache:
            cache[kr] = self.mi.load_dict(
                {
                    "type": "twosided",
                    "b": {"type": "conductor", "specular_reflectance": {"type": "rgb", "value": list(kr)}},
                }
            )
        return cache[kr]
