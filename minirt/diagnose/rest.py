"""Where the rest lies: the pixels no rule setting explains, grouped by what the reference knows of them.

A bug outside the rule table leaves pixels unexplained. To say where they are in words a student
understands, each pixel gets the facts the reference's trace knows about it (``features``): the shape its
primary ray hits (its index in the scene's ``[[shapes]]``, -1 for none), the hit distance t, lit or in
shadow, the signs of n·s and r·s, whether the ray meets the surface from inside or behind (d·n > 0), the
shapes its reflections show, and its distance in pixels from a silhouette (a change of the hit shape).

``groups`` then finds a few groups covering them, largest first: per shape hit, the conditions that hold
for (nearly) all of that shape's unexplained pixels and rule out most of its explained ones -- a decision
stump per fact, taken greedily: a yes/no fact where one answer holds for them, a threshold on t or on the
silhouette distance beyond which they all lie. A scikit-learn decision tree would find the same
thresholds, but its splits on the shape index (a category, not a number) and its leaves (impure, many)
read badly as sentences, and its import alone costs a second of every grade; this greedy search is a
page, deterministic, and its conditions are the sentence. Shapes whose groups have the same conditions
are merged into one group.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene

# A condition must keep this share of a group's unexplained pixels (a few stray pixels -- noise, a
# pixel a level past tolerance -- must not stop the condition that describes the rest) ...
KEEP = 0.97
# Where no condition keeps KEEP of them, the one that keeps at least SPLIT splits that part off as a group
# of its own (the rest is grouped next): a mirror floor whose wrong pixels are partly where it reflects a
# ball, partly in that ball's shadow.
SPLIT = 0.5
# ... and rule out at least this share of the explained pixels on the same shape still in the group
# (else it says nothing: "on the ball, lit" where the whole ball is lit).
RULE_OUT = 0.25
# At most this many conditions per group: a sentence, not a tree.
MAX_CONDITIONS = 3
# A threshold (on t, on the distance from a silhouette) wins over a fact of the trace (lit, the sides of
# n·s and r·s, a shape its reflections show) only where it rules out a quarter more: a fact names the step where
# the image departs, a threshold only where (the mirror floor's pixels that reflect a ball also lie
# nearer than some t, and "where it reflects the ball" is what the student can act on).
THRESHOLDS = ("t_above", "t_below", "silhouette_within")
THRESHOLD_WEIGHT = 0.8
# Explained pixels that the facts are traced for: every unexplained pixel, and a stride of the others.
SAMPLE = 16384
# A silhouette condition only for pixels this close to one (pixels): "near an edge" beyond it says little.
EDGE_PIXELS = 3


@dataclass
class Group:
    pixels: int
    shapes: list[int]
    conditions: dict[str, Any]
    sentence: str
    example: tuple[int, int]  # (x, y) of one pixel in the group: `minirt probe --image` shows it
    mask: np.ndarray = field(repr=False)
    fit: Any = None  # minirt.diagnose.fit.Fit: the exercise's formula fitted to the group (a grade's)

    def as_dict(self) -> dict[str, Any]:
        out = {
            "pixels": self.pixels,
            "shapes": self.shapes,
            "conditions": self.conditions,
            "sentence": self.sentence,
            "example": list(self.example),
        }
        if self.fit is not None:
            out["fit"] = self.fit.as_dict()
        return out


BOOLEAN = ("lit", "n_dot_s_positive", "r_dot_s_positive", "inside")


def primary(scene: Scene, rules: Rules, idx: np.ndarray) -> dict[str, Any]:
    """The reference's primary level at pixels ``idx`` under ``rules``, traced with recording on by the tracer
    itself (the same decisions as its image), as NumPy arrays of N rows: ``shape``, ``hit``, ``t`` (inf on
    a miss), ``p``, ``d``, ``n`` (the shape's own normal), ``ns`` (the shading normal), ``r`` (the
    highlight's reflected direction), ``lit``, the pixel's ``color`` and the level's ``local`` and ``bg``
    terms; and ``levels``, the recorded levels themselves."""
    import drjit as dr

    from minirt.reference.tracer import Tracer

    tr = Tracer(scene, rules, runtime=True)
    o, d = tr.primary_rays(idx.astype(np.uint32))
    with dr.scoped_set_flag(dr.JitFlag.FastMath, False):
        color, levels = tr.trace(o, d, record=True)
    lvl = levels[0]
    n = idx.size
    sid = np.asarray(lvl.shape_id).astype(np.int32)
    hit = sid >= 0

    def vec(a: Any) -> np.ndarray:
        return np.stack([np.broadcast_to(np.asarray(a[k], dtype=np.float64), (n,)) for k in range(3)], -1)

    dd, rec = vec(lvl.d), lvl.record
    ns = vec(rec["shading_normal"]) if "shading_normal" in rec else vec(lvl.n)
    lit = hit.copy()
    if "shadow_ts" in rec:
        limit = math.inf if rules.shadow_range == "any" else np.asarray(rec["light_dist"], dtype=np.float64)
        for ts in rec["shadow_ts"]:
            lit &= ~(np.broadcast_to(np.asarray(ts, dtype=np.float64), (n,)) < limit)
    return {
        "levels": levels,
        "shape": sid,
        "hit": hit,
        "t": np.where(hit, np.asarray(lvl.t, dtype=np.float64), math.inf),
        "p": vec(lvl.p),
        "d": dd,
        "n": vec(lvl.n),
        "ns": ns,
        "r": vec(rec["reflected"]) if "reflected" in rec else dd - 2 * (dd * ns).sum(-1, keepdims=True) * ns,
        "lit": lit,
        "color": vec(color),
        "local": vec(lvl.local),
        "bg": vec(lvl.bg),
    }


def features(scene: Scene, rules: Rules, idx: np.ndarray) -> dict[str, np.ndarray]:
    """The reference's facts about the primary rays of pixels ``idx`` under ``rules`` (see the module's
    docstring), each an (N,) array: shape, t, lit, n_dot_s_positive, r_dot_s_positive, inside,
    reflects (a bit per shape its reflections show, at any depth), from ``primary``."""
    f = primary(scene, rules.traced(), idx)
    levels, sid, hit, t, p, dd, ns, r, lit = (f[k] for k in ("levels", "shape", "hit", "t", "p", "d", "ns", "r", "lit"))
    n = idx.size
    to_light = np.asarray(scene.light.position, dtype=np.float64) - p
    with np.errstate(invalid="ignore", divide="ignore"):
        s = to_light / np.linalg.norm(to_light, axis=-1, keepdims=True)
    # the shapes the pixel's reflections show, at any depth: a bit per shape (scenes of up to 63 shapes)
    reflected = np.zeros(n, dtype=np.int64)
    root = np.arange(n)
    for deeper in levels[1:]:
        if deeper.parent is None or len(scene.shapes) > 63:
            break
        root = root[np.asarray(deeper.parent).astype(np.int64)]
        ids = np.asarray(deeper.shape_id).astype(np.int64)
        np.bitwise_or.at(reflected, root[ids >= 0], np.left_shift(1, ids[ids >= 0]))
    return {
        "shape": sid,
        "t": t,
        "lit": lit,
        "n_dot_s_positive": hit & ((s * ns).sum(-1) > 0),
        "r_dot_s_positive": hit & ((s * r).sum(-1) > 0),
        "inside": hit & ((dd * f["n"]).sum(-1) > 0),
        "reflects": np.where(hit, reflected, 0),
    }


def silhouette_distance(shape_id: np.ndarray) -> np.ndarray:
    """(H, W) distance in pixels from each pixel to the nearest pixel whose neighbour hits another shape
    (or none): how far the pixel is from a silhouette. SciPy's exact Euclidean distance transform."""
    from scipy import ndimage

    edge = np.zeros(shape_id.shape, dtype=bool)
    dx = shape_id[:, 1:] != shape_id[:, :-1]
    dy = shape_id[1:, :] != shape_id[:-1, :]
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:, :] |= dy
    edge[:-1, :] |= dy
    if not edge.any():
        return np.full(shape_id.shape, np.inf)
    return ndimage.distance_transform_edt(~edge)


def groups(
    scene: Scene, rules: Rules, unexplained: np.ndarray, first_hits: tuple[np.ndarray, np.ndarray]
) -> list[Group]:
    """The groups covering the ``unexplained`` (H, W) pixels under ``rules`` (the diagnosis's answer),
    largest first; ``first_hits``: the full image's primary shape ids and t (``VariantCache.first_hits``),
    from which t's thresholds and the silhouettes are read exactly."""
    h, w = unexplained.shape
    flat = unexplained.reshape(-1)
    u_idx = np.flatnonzero(flat)
    if u_idx.size == 0:
        return []
    rest = np.flatnonzero(~flat)
    e_idx = rest[:: max(1, rest.size // SAMPLE)]
    e_weight = rest.size / max(1, e_idx.size)
    idx = np.concatenate([u_idx, e_idx])
    f = features(scene, rules, idx)
    sid_all, t_all = first_hits
    f["silhouette"] = silhouette_distance(sid_all.reshape(h, w)).reshape(-1)[idx]
    is_u = np.arange(idx.size) < u_idx.size
    weight = np.where(is_u, 1.0, e_weight)

    found: list[tuple[int, dict[str, Any], np.ndarray]] = []  # (shape, conditions, the group's pixels in idx)
    for shape in _by_count(f["shape"][is_u]):
        left = is_u & (f["shape"] == shape)
        while left.sum():
            others = ~is_u & (f["shape"] == shape)
            conds, inside = _conditions(f, left, others, weight, sid_all, t_all, shape, KEEP)
            if not conds:  # nothing holds for nearly all of them: split off the part a condition describes
                conds, inside = _conditions(f, left, others, weight, sid_all, t_all, shape, SPLIT)
            members = left & inside
            if not conds or not members.any():  # no condition describes the rest: "anywhere on the shape"
                conds, members = {}, left
            found.append((shape, conds, members))
            left = left & ~members
    merged: dict[str, tuple[list[int], dict[str, Any], np.ndarray]] = {}
    for shape, conds, members in found:
        key = repr(sorted(conds.items()))
        if key in merged:
            merged[key][0].append(shape)
            merged[key] = (merged[key][0], conds, merged[key][2] | members)
        else:
            merged[key] = ([shape], conds, members)
    out = []
    for shapes, conds, members in merged.values():
        mask = np.zeros(h * w, dtype=bool)
        mask[idx[members]] = True
        # the example: the member nearest the group's centroid (away from its edges, where terms are small)
        at = idx[members]
        ys, xs = at // w, at % w
        first = int(at[np.argmin((ys - ys.mean()) ** 2 + (xs - xs.mean()) ** 2)])
        shapes = sorted(shapes)
        n = int(members.sum())
        out.append(
            Group(n, shapes, conds, sentence(scene, n, shapes, conds), (first % w, first // w), mask.reshape(h, w))
        )
    out.sort(key=lambda g: (-g.pixels, g.shapes, repr(sorted(g.conditions.items()))))
    return out


def _by_count(values: np.ndarray) -> list[int]:
    """The distinct values, most frequent first (ties: the lower value first)."""
    vals, counts = np.unique(values, return_counts=True)
    return [int(vals[k]) for k in sorted(range(vals.size), key=lambda k: (-counts[k], vals[k]))]


def _conditions(
    f: dict[str, np.ndarray],
    u: np.ndarray,
    e: np.ndarray,
    weight: np.ndarray,
    sid_all: np.ndarray,
    t_all: np.ndarray,
    shape: int,
    keep_first: float,
) -> tuple[dict[str, Any], np.ndarray]:
    """Greedy decision stumps: the conditions that rule out the most of the explained pixels ``e``
    (weighted) while keeping the unexplained ones ``u``, best first, at most MAX_CONDITIONS: the first
    keeping ``keep_first`` of them (KEEP; or SPLIT, where it splits a part off), each later one KEEP of
    those still in. Returns them and the mask (over the traced pixels) of where they all hold."""
    conds: dict[str, Any] = {}
    inside = np.ones(u.size, dtype=bool)
    keep = keep_first
    for _ in range(MAX_CONDITIONS):
        cu, ce = u & inside, e & inside
        base, n_u = (weight * ce).sum(), cu.sum()
        if base == 0:
            break
        best = None
        for name, holds, value in _stumps(f, cu, sid_all, t_all, shape, conds):
            kept = (cu & holds).sum() / n_u
            if kept < keep:
                continue
            out = (weight * (ce & ~holds)).sum() / base
            score = kept * out * (THRESHOLD_WEIGHT if name in THRESHOLDS else 1.0)
            if out >= RULE_OUT and (best is None or score > best[0]):
                best = (score, name, value, holds)
        if best is None:
            break
        _, name, value, holds = best
        conds[name] = value
        inside &= holds
        keep = KEEP
    return conds, inside


def _stumps(f, cu, sid_all, t_all, shape, conds):
    """(name, mask, value) of each candidate condition on the unexplained pixels ``cu``."""
    for name in BOOLEAN:
        if name in conds or not cu.any():
            continue
        yes = f[name][cu].mean()
        v = bool(yes >= 0.5)
        yield name, f[name] == v, v
    if "reflects" not in conds and cu.any():
        bits = f["reflects"][cu]
        shown = [(int(((bits >> k) & 1).sum()), -k) for k in range(63) if ((bits >> k) & 1).any()]
        if shown:
            k = -max(shown)[1]
            yield "reflects", ((f["reflects"] >> k) & 1) == 1, k
    if shape >= 0 and cu.any():
        t = f["t"][cu]
        on = t_all[sid_all == shape]
        if "t_above" not in conds:
            lo = float(np.quantile(t, 1 - KEEP))
            below = on[on < lo]
            x = _between(float(below.max()) if below.size else 0.0, lo)
            yield "t_above", f["t"] > x, x
        if "t_below" not in conds:
            hi = float(np.quantile(t, KEEP))
            above = on[on > hi]
            x = _between(hi, float(above.min()) if above.size else hi * 2)
            yield "t_below", f["t"] < x, x
    if "silhouette_within" not in conds and cu.any():
        k = float(np.quantile(f["silhouette"][cu], KEEP))
        if k <= EDGE_PIXELS:
            k = math.ceil(k)
            yield "silhouette_within", f["silhouette"] <= k, k


def _between(lo: float, hi: float) -> float:
    """A short number x with lo <= x < hi (lo < hi), for a threshold the sentence shows."""
    from minirt.diagnose.search import simplest

    if not lo < hi:
        return lo
    x = simplest(lo, hi)
    return x if x < hi else lo


def _shape_words(scene: Scene, k: int) -> str:
    if k < 0:
        return "the background (the reference's ray hits nothing)"
    s = scene.shapes[k]
    kind = "ball" if isinstance(s, Ball) else "plane"
    name = f", material {s.material.name}" if s.material.name else ""
    return f"the {kind} (shape {k}{name})"


def _condition_words(scene: Scene, name: str, v: Any) -> str:
    words = {
        "lit": "lit by the light" if v else "in shadow",
        "n_dot_s_positive": "facing the light (n·s > 0)" if v else "facing away from the light (n·s ≤ 0)",
        "r_dot_s_positive": "on the highlight's side (r·s > 0)" if v else "away from the highlight (r·s ≤ 0)",
        "inside": "seen from inside or from behind (d·n > 0)" if v else "seen from outside (d·n < 0)",
    }
    if name in words:
        return words[name]
    if name == "reflects":
        return f"where its reflection shows {_shape_words(scene, v)}"
    if name == "t_above":
        return f"at t > {v:g}"
    if name == "t_below":
        return f"at t < {v:g}"
    return f"within {v:g} pixels of a silhouette"


def sentence(scene: Scene, n: int, shapes: list[int], conds: dict[str, Any]) -> str:
    """The group in words: where its pixels are, and what that suggests."""
    where = " and ".join(_shape_words(scene, k) for k in shapes)
    cond = ", ".join(_condition_words(scene, k, v) for k, v in conds.items())
    head = f"{n:,} pixel{'s' if n != 1 else ''} on {where}" + (f", {cond}" if cond else "")
    hint = ""
    if "t_above" in conds:
        hint = f": nothing beyond t = {conds['t_above']:g} is drawn as the model draws it"
    elif conds.get("lit") is False:
        hint = ": the shadowed part is drawn otherwise (the shadow test, or what is added in shadow)"
    elif conds.get("lit") is True:
        hint = ": the lit part is drawn otherwise (the diffuse or specular term)"
    elif "reflects" in conds:
        hint = f": shape {conds['reflects']} is drawn otherwise where it is seen in a reflection"
    elif "silhouette_within" in conds:
        hint = ": the edges are drawn otherwise (the intersection test near a grazing ray)"
    return head + (hint or ": no rule setting draws them as your image does") + "."
