"""The rest, fitted: the exercise's shading formula fitted to the pixels no rule setting explains.

A bug outside the rule table leaves groups of pixels (minirt.diagnose.rest). On each shape of a group this
module fits, by linear least squares on the reference's own geometry (scipy.linalg.lstsq), per channel

    colour = ambient + diffuse · L · f(s·n) + specular · L · g(r·s) + reflection · R

where L is the light's colour, R the colour the reference's reflected ray brings back (the scene's
reflection colour times it: 1 means "as the scene says"), and f, g the diffuse and highlight terms as the
answer's clamp rule shapes them (the answer's exponent). The constant absorbs the background that rule
background adds at a hit. The colours are free, negative ones included (real solutions derive materials
that way), and so are the discrete choices a real solution gets wrong, each tried:

- the light as a position (s = (L - p)/|L - p|) or as one direction (s = L/|L|: rule light);
- the normal as the reference has it, or negated;
- shadows tested (the reference's shadow rays under the answer's rules) or none at all.

The geometry of each choice comes from the reference tracer itself, traced on the group's pixels under the
answer's rules with rule light and shadow_rays set accordingly; the normal's sign is applied here. The
channels of a pixel that an 8-bit image clamps (level 0 or 255) say only "at most" or "at least": they are
left out of the fit and checked afterwards like every other. A choice *reproduces* a pixel when the fitted
colour, written under the answer's output rules, is within the grade's tolerance of the image (one level, or
FLOAT_TOL); the choice that reproduces most pixels wins, the exercise's reading first among equals.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from minirt.diagnose import rest
from minirt.diagnose.target import Target
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Scene

# A group's shape gets a fit when it has at least this many pixels: four unknowns a channel need more
# equations than that to say anything (twice as many, and a few to spare for clamped channels).
MIN_PIXELS = 12
# A fit "reproduces the group" when it reproduces at least this share of its pixels on every shape: the
# rest are pixels where the fitted formula's own decisions (a shadow's edge) fall otherwise.
REPRODUCES = 0.95
# ... and when every colour it fits lies within +-PLAUSIBLE: a material's colours are of order 1 (a scene's
# are in [0, 1]; a student's formula may double one or make it negative), and a fit that needs a
# highlight of 280 to match a handful of pixels fits their noise, not a formula anyone wrote.
PLAUSIBLE = 4.0


def choices(rules: Rules) -> list[tuple[str, float, bool]]:
    """(light, normal sign, shadows) to try: the answer's own first, then each departure from it."""
    lights = [rules.light, *[v for v in ("position", "direction") if v != rules.light]]
    shadows = [rules.shadow_rays, *([False] if rules.shadow_rays else [])]
    return list(itertools.product(lights, (1.0, -1.0), shadows))


@dataclass
class ShapeFit:
    shape: int
    pixels: int  # reproduced
    of: int
    parameters: dict[str, Any]
    sentence: str

    @property
    def plausible(self) -> bool:
        colours = [c for k in ("ambient", "diffuse", "specular", "reflection") for c in self.parameters[k]]
        return all(abs(c) <= PLAUSIBLE for c in colours)


@dataclass
class Fit:
    pixels: int
    of: int
    shapes: list[ShapeFit] = field(default_factory=list)
    reflected: bool = False  # the group lies where another shape is seen in a reflection: not fitted here

    @property
    def reproduces(self) -> bool:
        return bool(self.shapes) and all(s.pixels >= REPRODUCES * s.of and s.plausible for s in self.shapes)

    @property
    def sentence(self) -> str:
        if self.reflected:
            return "what differs here is the shape seen in the reflection: it is fitted where it is seen directly."
        if not self.shapes:
            return "too few pixels on any one shape to fit the exercise's formula to them."
        said = "; ".join(s.sentence for s in self.shapes)
        if self.reproduces:
            return said
        return (
            f"no setting of the exercise's formula (its colours, the light as a position or a direction, the "
            f"normal's sign, shadows or none) reproduces these pixels: the closest reproduces {self.pixels} of "
            f"{self.of}"
        )

    def as_dict(self) -> dict[str, Any]:
        counts = {"pixels": self.pixels, "of": self.of, "reproduces": self.reproduces, "reflected": self.reflected}
        return {
            **counts,
            "parameters": {str(s.shape): s.parameters for s in self.shapes},
            "sentence": self.sentence,
        }


def fit_groups(scene: Scene, rules: Rules, target: Target, groups: list) -> None:
    """Attach a ``Fit`` to each group (``rest.Group.fit``)."""
    for g in groups:
        if g.conditions.get("reflects") is not None:
            # drawn otherwise where another shape is seen in a reflection: that shape's colours are what
            # differ, and its own group (if it has one) is where they are fitted
            g.fit = Fit(0, int(g.mask.sum()), [], reflected=True)
            continue
        at = np.flatnonzero(g.mask.reshape(-1))
        keys = {(light, sh) for light, _, sh in choices(rules)}
        geo = {(light, sh): _geometry(scene, rules, at, light, sh) for light, sh in sorted(keys)}
        sid = geo[(rules.light, rules.shadow_rays)]["shape"]
        fits = []
        for shape in g.shapes:
            mine = sid == shape
            if mine.sum() < MIN_PIXELS:
                continue
            fits.append(_fit_shape(scene, rules, target, at, mine, geo, shape))
        g.fit = Fit(sum(f.pixels for f in fits), int(at.size), fits)


def _geometry(scene: Scene, rules: Rules, at: np.ndarray, light: str, shadows: bool) -> dict[str, np.ndarray]:
    """The reference's primary-level facts at pixels ``at`` under ``rules`` with rule light and shadow_rays
    set (``rest.primary``): shape id, s, the shading normal, the highlight's r, lit, and the colour its
    reflection adds."""
    f = rest.primary(scene, replace(rules.traced(), light=light, shadow_rays=shadows), at)
    n = at.size
    if light == "direction":
        lp = np.asarray(scene.light.position, dtype=np.float64)
        s = np.broadcast_to(lp / (np.linalg.norm(lp) or 1.0), (n, 3))
    else:
        to_light = np.asarray(scene.light.position, dtype=np.float64) - f["p"]
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.nan_to_num(to_light / np.linalg.norm(to_light, axis=-1, keepdims=True))
    back = f["color"] - f["local"] - f["bg"]  # what the reflected ray adds (the scene's weight times it)
    return {"shape": f["shape"], "s": s, "n": f["ns"], "r": f["r"], "lit": f["lit"], "reflection": back}


def _terms(rules: Rules, s: np.ndarray, n: np.ndarray, r: np.ndarray, lit: np.ndarray) -> tuple[np.ndarray, ...]:
    """(f, g): the diffuse and highlight factors as the answer's clamp rule shapes them."""
    sn = (s * n).sum(-1)
    rs = (r * s).sum(-1)
    with np.errstate(over="ignore", invalid="ignore"):
        pw = np.power(rs, rules.specular_exponent)
    if rules.clamp is True:
        f, g = np.maximum(sn, 0.0), np.where((sn > 0) & (rs > 0), pw, 0.0)
    elif rules.clamp == "specular":
        f, g = sn, np.where(rs > 0, pw, 0.0)
    else:
        f, g = sn, pw
    return np.where(lit, f, 0.0), np.where(lit, np.nan_to_num(g), 0.0)


def _fit_shape(scene, rules, target, at, mine, geo, shape) -> ShapeFit:
    idx = at[mine]
    wanted = _decoded(target, rules, idx)  # (N, 3) linear colours, NaN where clamped
    lc = np.asarray(scene.light.color, dtype=np.float64)
    best = None
    for k, (light, sign, shadows) in enumerate(choices(rules)):
        g = geo[(light, shadows)]
        f_d, f_s = _terms(rules, g["s"][mine], sign * g["n"][mine], g["r"][mine], g["lit"][mine])
        refl = g["reflection"][mine]
        params, pred = _solve(wanted, f_d, f_s, refl, lc)
        d = target.difference(pred, rules, idx)
        ok = 0 if d is None else int((~target.beyond(d)).sum())
        err = float(np.nansum((pred - np.nan_to_num(wanted)) ** 2))
        key = (-ok, k, err)
        if best is None or key < best[0]:
            best = (key, ok, light, sign, shadows, params)
    _, ok, light, sign, shadows, params = best
    if rules.background == "on-hit":  # the constant holds the background added at the hit: not the ambient
        params["ambient"] = [_round(a - b) for a, b in zip(params["ambient"], scene.background, strict=True)]
    words = _describe(scene, rules, shape, light, sign, shadows, params)
    parameters = {
        **params,
        "light": "position" if light == "position" else f"direction {_vec(_direction(scene))}",
        "normal": "as the answer's" if sign > 0 else "negated",
        "shadows": "tested" if shadows else "none",
    }
    return ShapeFit(shape, ok, int(idx.size), parameters, words)


def _solve(wanted, f_d, f_s, refl, lc) -> tuple[dict[str, Any], np.ndarray]:
    """Per channel, least squares over the unclamped channels; columns that are zero everywhere are left out
    (their colour reported as 0)."""
    from scipy.linalg import lstsq

    n = f_d.size
    out = {"ambient": [0.0] * 3, "diffuse": [0.0] * 3, "specular": [0.0] * 3, "reflection": [0.0] * 3}
    pred = np.zeros((n, 3))
    for c in range(3):
        cols = {
            "ambient": np.ones(n),
            "diffuse": lc[c] * f_d,
            "specular": lc[c] * f_s,
            "reflection": refl[:, c],
        }
        names = [k for k, v in cols.items() if np.any(v != 0)]
        a = np.stack([cols[k] for k in names], -1)
        ok = ~np.isnan(wanted[:, c])
        coef = np.zeros(len(names))
        if ok.sum() >= len(names):
            coef = lstsq(a[ok], wanted[ok, c], lapack_driver="gelsy")[0]
        for k, v in zip(names, coef, strict=True):
            out[k][c] = float(v)
        pred[:, c] = a @ coef
    rounded = {k: [_round(x) for x in v] for k, v in out.items()}
    return rounded, pred


def _decoded(target: Target, rules: Rules, idx: np.ndarray) -> np.ndarray:
    """The image's colours at ``idx`` as linear values (the middle of each 8-bit level's interval under the
    answer's encoding and gamma), NaN where a channel is clamped (level 0 or 255; float: 0 or 1)."""
    img = target.in_layout(rules).reshape(-1, 3)[idx].astype(np.float64)
    if target.is_float:
        v = img
        clamped = (v <= 0.0) | (v >= 1.0)
    else:
        lo_edge = {"round": -0.5, "floor": 0.0, "floor256": 0.0}[rules.encoding]
        scale = 256.0 if rules.encoding == "floor256" else 255.0
        v = (img + lo_edge + 0.5) / scale
        clamped = (img <= 0) | (img >= 255)
    if rules.gamma == "srgb":
        v = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    elif rules.gamma == "2.2":
        v = np.power(np.clip(v, 0, None), 2.2)
    return np.where(clamped, np.nan, v)


def _round(x: float) -> float:
    """Three significant digits; below 1e-6 (a colour no 8-bit level shows, least squares' round-off) 0."""
    if not math.isfinite(x):
        return x
    return 0.0 if abs(x) < 1e-6 else float(f"{x:.3g}")


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.2g}" for x in v) + ")"


def _direction(scene: Scene) -> tuple[float, float, float]:
    lp = np.asarray(scene.light.position, dtype=np.float64)
    return tuple(float(x) for x in lp / (np.linalg.norm(lp) or 1.0))


def _describe(
    scene: Scene, rules: Rules, shape: int, light: str, sign: float, shadows: bool, params: dict[str, Any]
) -> str:
    kind = "ball" if isinstance(scene.shapes[shape], Ball) else "plane"
    terms = [f"ambient {_vec(params['ambient'])}"]
    s_words = "s" if light == "position" else f"s one fixed direction {_vec(_direction(scene))}"
    n_words = "n" if sign > 0 else "(−n)"
    if any(params["diffuse"]):
        terms.append(f"diffuse {_vec(params['diffuse'])}·({s_words}·{n_words})")
    if any(params["specular"]):
        terms.append(f"specular {_vec(params['specular'])}·(r·s)^e")
    if any(params["reflection"]):
        terms.append(f"reflection {_vec(params['reflection'])} × the scene's reflected colour")
    what = []  # where the fit departs from the answer's rules
    if light != rules.light:
        what.append("the light's position used as a direction" if light == "direction" else "s towards the light")
    if sign < 0:
        what.append("the normal negated")
    if shadows != rules.shadow_rays:
        what.append("no shadows")
    tail = f": {', '.join(what)}" if what else ""
    return f"on {kind} {shape} your image is {' + '.join(terms)}{tail}"
