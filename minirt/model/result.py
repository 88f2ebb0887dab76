"""RenderResult: the one type every backend returns (the reference tracer and every oracle).

All arrays are NumPy, row-major images of shape (H, W) or (H, W, 3), y = 0 the top row:
- ``hit`` (bool), ``shape_id`` (int32, -1 on a miss), ``t`` (float64, distance along the primary
  ray from its origin, +inf on a miss), ``position`` and ``normal`` (float64, 0 on a miss);
- ``color`` (float64, linear, before clamping) where the backend shades, else None;
- ``terms``: the shading terms that add up to ``color`` (ambient, diffuse, specular, reflection,
  background) where the backend has them;
- ``image8``: the backend's own 8-bit bitmap where it writes one (POV-Ray rounds exactly as the
  exercise does, from more precision than its half-float EXR keeps); else derived from ``color``;
- ``aux``: backend-specific per-pixel buffers the harness needs (e.g. Mitsuba's light distance);
- ``meta``: backend, version, settings, rules, effects simulated/skipped, timings, commands run.
A backend that could not run returns status "skip" or "error" with a reason and no buffers.

A backend may hand a 3-vector buffer over as ``Planes``, its three (H, W) components: the arrays its
kernels wrote, one allocation each, which NumPy cannot view as one (H, W, 3) array. The field stacks them
into one the first time it is read, and keeps that; a writer that wants the components (an EXR's channels)
takes the buffer as it is held (``held``, ``components``), and never pays for the stack. The reference
tracer's large renders do this: the stack is a copy of every buffer, as long as the trace itself
(three_balls 1024^2, f64).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

TERMS = ("ambient", "diffuse", "specular", "reflection", "background")


class Planes(tuple):
    """An (H, W, 3) buffer as its three (H, W) components (x, y, z), stacked when read (see the module)."""

    __slots__ = ()

    def stack(self) -> np.ndarray:
        return np.stack(self, axis=-1)


class _Vector:
    """A field holding an (H, W, 3) array or None, which may be set as ``Planes`` (stacked on first read)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.slot = "_" + name

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return None  # the dataclass field's default
        v = obj.__dict__.get(self.slot)
        if isinstance(v, Planes):
            v = obj.__dict__[self.slot] = v.stack()
        return v

    def __set__(self, obj: Any, value: Any) -> None:
        obj.__dict__[self.slot] = value


class _Terms:
    """The field ``terms``: a dict of (H, W, 3) arrays (None: an empty one), whose values may be set as
    ``Planes``; they are stacked when the dict is first read."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.slot = "_" + name

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return None  # the dataclass field's default: a new dict, made by __set__
        d = obj.__dict__[self.slot]
        if any(isinstance(v, Planes) for v in d.values()):
            d.update({k: v.stack() for k, v in d.items() if isinstance(v, Planes)})
        return d

    def __set__(self, obj: Any, value: Any) -> None:
        obj.__dict__[self.slot] = {} if value is None else value


@dataclass
class RenderResult:
    backend: str
    width: int
    height: int
    status: str = "ok"  # "ok" | "skip" | "error"
    reason: str = ""
    hit: np.ndarray | None = None
    shape_id: np.ndarray | None = None
    t: np.ndarray | None = None
    position: np.ndarray | None = _Vector()  # type: ignore[assignment]
    normal: np.ndarray | None = _Vector()  # type: ignore[assignment]
    color: np.ndarray | None = _Vector()  # type: ignore[assignment]
    image8: np.ndarray | None = None
    terms: dict[str, np.ndarray] = _Terms()  # type: ignore[assignment]
    aux: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def held(self, name: str) -> np.ndarray | Planes | None:
        """The vector buffer ``name`` ("color", "position", "normal" or a term) as it is held: an (H, W, 3)
        array, ``Planes`` (never stacked by this), or None."""
        return self.__dict__["_terms"].get(name) if name in TERMS else self.__dict__["_" + name]

    def components(self, name: str) -> tuple[np.ndarray, ...] | None:
        """The three (H, W) components of the vector buffer ``name`` (as ``held``), without stacking them
        (views of the array when it is one); None where there is none."""
        v = self.held(name)
        if v is None or isinstance(v, Planes):
            return v
        return tuple(v[..., k] for k in range(3))

    def terms_names(self) -> list[str]:
        """The names of the terms held, in order, without stacking any."""
        return list(self.__dict__["_terms"])

    @property
    def traced(self) -> np.ndarray | None:
        """(H, W) bool: the pixels a backend that renders chosen pixels traced (aux "rendered"); None when it
        traced every pixel. The others hold no data and are judged nowhere."""
        r = self.aux.get("rendered")
        return None if r is None or r.all() else r

    @classmethod
    def failed(cls, backend: str, width: int, height: int, status: str, reason: str, **meta: Any) -> RenderResult:
        assert status in ("skip", "error")
        meta = {**meta, "backend": backend}
        return cls(backend=backend, width=width, height=height, status=status, reason=reason, meta=meta)

    def color8(self) -> np.ndarray | None:
        """The exercise's bitmap: clamp to [0, 1], then floor(c * 255 + 0.5), no gamma."""
        if self.image8 is not None:
            return self.image8
        v = self.held("color")
        if isinstance(v, Planes):  # component by component: the colour is not stacked for its bitmap
            out = np.empty((*v[0].shape, 3), np.uint8)
            for k, c in enumerate(v):
                out[..., k] = to8(c)
            return out
        return None if v is None else to8(v)


def to8(color: np.ndarray) -> np.ndarray:
    """clamp(c, 0, 1), then floor(c * 255 + 0.5) as 8 bits (NaN as 0): the same roundings in one buffer,
    in place, rather than a new array for each step."""
    c = np.nan_to_num(np.asarray(color), nan=0.0)  # a copy, of the colour's own float type
    if not np.issubdtype(c.dtype, np.floating):
        c = c.astype(np.float64)
    np.clip(c, 0.0, 1.0, out=c)
    np.multiply(c, 255.0, out=c)
    np.add(c, 0.5, out=c)
    np.floor(c, out=c)
    return c.astype(np.uint8)


def geometry_from_flat(
    width: int, height: int, shape_id: np.ndarray, t: np.ndarray, position: np.ndarray, normal: np.ndarray
) -> dict[str, np.ndarray]:
    """Reshape flat per-ray buffers (N,), (N, 3) into image buffers, with misses normalised."""
    sid = np.asarray(shape_id, dtype=np.int32).reshape(height, width)
    hit = sid >= 0
    t = np.where(hit, np.asarray(t, dtype=np.float64).reshape(height, width), np.inf)
    pos = np.where(hit[..., None], np.asarray(position, dtype=np.float64).reshape(height, width, 3), 0.0)
    nrm = np.where(hit[..., None], np.asarray(normal, dtype=np.float64).reshape(height, width, 3), 0.0)
    return {"hit": hit, "shape_id": sid, "t": t, "position": pos, "normal": nrm}


def edge_classes(ref: RenderResult) -> dict[str, np.ndarray]:
    """Pixels whose 3x3 neighbourhood crosses a silhouette, a shadow edge or a terminator -- seen
    directly, or further down the ray tree (in a reflection: the reference's aux ray_tree labels each
    pixel by every decision its colour rests on). The harness reports them apart (minirt.harness.shading);
    an oracle that chooses its pixels traces where they are (minirt.oracles.exact).

    Kept on the result for the buffers it was made from (a check asks it of one reference for every oracle
    and more: 40 times in the bundled scenes' check, ~15 ms each at 256^2); the masks are read-only."""
    made_of = (ref.shape_id, ref.terms.get("diffuse"), ref.terms.get("specular"), ref.aux.get("ray_tree"))
    kept = ref.__dict__.get("_edge_classes")
    if kept is not None and all(a is b for a, b in zip(kept[0], made_of, strict=True)):
        return dict(kept[1])
    out = _edge_classes(ref)
    for mask in out.values():
        mask.setflags(write=False)
    ref.__dict__["_edge_classes"] = (made_of, out)
    return dict(out)


def changes(labels: np.ndarray) -> np.ndarray:
    """(H, W) bool: where a label differs from another in its 3x3 neighbourhood (the image's edge rows and
    columns repeated outwards) -- scipy.ndimage's maximum_filter != minimum_filter (size 3, mode "nearest"),
    computed as a max and a min over rows, then over columns (both separate), without importing
    scipy.ndimage (~0.3 CPU-s, more than the check of a small scene spends on its edges)."""
    padded = np.pad(labels, 1, mode="edge")
    h, w = labels.shape

    def box(op) -> np.ndarray:
        rows = op(op(padded[:, 0:w], padded[:, 1 : w + 1]), padded[:, 2 : w + 2])
        return op(op(rows[0:h], rows[1 : h + 1]), rows[2 : h + 2])

    return box(np.maximum) != box(np.minimum)


def _edge_classes(ref: RenderResult) -> dict[str, np.ndarray]:
    sil = changes(ref.shape_id)
    lit = (ref.terms.get("diffuse", np.zeros((ref.height, ref.width, 3))) > 0).any(-1) | (
        ref.terms.get("specular", np.zeros((ref.height, ref.width, 3))) > 0
    ).any(-1)
    light_edge = changes(lit.astype(np.int8)) & ~sil
    out = {"silhouette": sil, "shadow_or_terminator": light_edge}
    if "ray_tree" in ref.aux:
        out["in_reflection"] = changes(ref.aux["ray_tree"]) & ~sil & ~light_edge
    return out
