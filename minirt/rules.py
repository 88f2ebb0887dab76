"""The model rules: where the exercise's pseudo-code and established renderers disagree.

Each difference is a named rule with two values. Profile ``exercise`` takes the pseudo-code's
literal reading, profile ``conventional`` what POV-Ray does. A scene's ``[model]`` table overrides
single rules. This module also derives the *effects* a scene needs, so the tracer simulates only those.

| rule             | exercise (literal)          | conventional                          |
|------------------|-----------------------------|---------------------------------------|
| background       | "on-hit" (added at each hit) | "on-miss" (a miss returns it)        |
| near_root_only   | true (ball invisible inside) | false (nearest root with t > 0)      |
| shadow_range     | "any" (anything on the ray)  | "to-light" (only before the light)   |
| two_sided        | false (normals as given)     | true (normals face the ray)          |
| clamp            | false (s·n, (r·s)^8 raw)     | true (max(0, ·), no specular if s·n<=0) |
| offset           | 1e-6 (hit + offset·normal)   | "error-bound" (pbrt-style bound)     |
| ray_origin       | "image-plane"                | "image-plane" (or "camera")          |
| pixel_sample     | "corner"                     | "corner" (or "center")               |
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from minirt.scene import Ball, Plane, Scene


@dataclass(frozen=True)
class Rules:
    background: str = "on-hit"
    near_root_only: bool = True
    shadow_range: str = "any"
    two_sided: bool = False
    clamp: bool = False
    offset: float | str = 1e-6
    ray_origin: str = "image-plane"
    pixel_sample: str = "corner"

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def differs(self, other: Rules) -> list[str]:
        """Names of the rules whose values differ between self and other."""
        return [f.name for f in fields(self) if getattr(self, f.name) != getattr(other, f.name)]


PROFILES: dict[str, Rules] = {
    "exercise": Rules(),
    "conventional": Rules(
        background="on-miss",
        near_root_only=False,
        shadow_range="to-light",
        two_sided=True,
        clamp=True,
        offset="error-bound",
    ),
}

# The values each rule accepts; used for validation and for the CLI's help.
CHOICES: dict[str, tuple[Any, ...]] = {
    "background": ("on-hit", "on-miss"),
    "near_root_only": (True, False),
    "shadow_range": ("any", "to-light"),
    "two_sided": (True, False),
    "clamp": (True, False),
    "offset": ("error-bound", "<a number >= 0>"),
    "ray_origin": ("image-plane", "camera"),
    "pixel_sample": ("corner", "center"),
}


def _check_value(name: str, value: Any) -> str | None:
    if name == "offset":
        if value == "error-bound":
            return None
        if isinstance(value, int | float) and not isinstance(value, bool):
            if math.isfinite(value) and value >= 0:
                return None
            return f"model.offset: must be a finite number >= 0 or 'error-bound', got {value}"
        return f"model.offset: must be a number >= 0 or 'error-bound', got {value!r}"
    allowed = CHOICES[name]
    if isinstance(allowed[0], bool):
        if not isinstance(value, bool):
            return f"model.{name}: must be true or false, got {value!r}"
        return None
    if value not in allowed:
        return f"model.{name}: must be one of {', '.join(map(repr, allowed))}, got {value!r}"
    return None


def validate_model_table(profile: str, model: dict[str, Any]) -> list[str]:
    """Problems with a scene's profile name and [model] overrides, one line each (empty if fine)."""
    problems = []
    if profile not in PROFILES:
        problems.append(f"render.profile: unknown profile {profile!r} (known: {', '.join(PROFILES)})")
    for name, value in model.items():
        if name not in CHOICES:
            problems.append(f"model.{name}: unknown rule (known: {', '.join(CHOICES)})")
            continue
        p = _check_value(name, value)
        if p:
            problems.append(p)
    return problems


def resolve(scene: Scene, profile: str | None = None, overrides: dict[str, Any] | None = None) -> Rules:
    """The rules for a render: the profile (scene's, unless given), then the scene's [model], then overrides."""
    from minirt.errors import MinirtError

    name = profile or scene.profile
    if name not in PROFILES:
        raise MinirtError(f"unknown profile {name!r} (known: {', '.join(PROFILES)})")
    rules = PROFILES[name]
    merged = {**scene.model, **(overrides or {})}
    problems = validate_model_table(name, merged)
    if problems:
        raise MinirtError(*problems)
    if isinstance(merged.get("offset"), int) and not isinstance(merged.get("offset"), bool):
        merged["offset"] = float(merged["offset"])
    return replace(rules, **merged)


def flipped(rules: Rules, name: str) -> Rules:
    """The rules with one rule switched to its other value (for attribution and tests)."""
    current = getattr(rules, name)
    if name == "offset":
        return replace(rules, offset=1e-6 if current == "error-bound" else "error-bound")
    a, b = CHOICES[name][:2]
    return replace(rules, **{name: b if current == a else a})


# ---------------------------------------------------------------------------------------------
# Effects: what a scene actually calls for.


@dataclass(frozen=True)
class Effects:
    """Which parts of the model a render has to simulate. Skipped parts contribute exactly zero."""

    ambient: bool
    diffuse: bool
    specular: bool
    shadows: bool
    reflection: bool
    reflection_depth: int  # bounces that can actually contribute (<= max_depth)
    background: bool

    def simulated(self) -> list[str]:
        out = [n for n in ("ambient", "diffuse", "specular", "shadows", "background") if getattr(self, n)]
        if self.reflection:
            out.append(f"reflection(depth {self.reflection_depth})")
        return out

    def skipped(self) -> list[str]:
        return [
            n for n in ("ambient", "diffuse", "specular", "shadows", "reflection", "background") if not getattr(self, n)
        ]

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _any(c: tuple[float, float, float]) -> bool:
    return any(x != 0.0 for x in c)


def _inside(ball: Ball, p: tuple[float, float, float]) -> bool:
    return sum((p[i] - ball.center[i]) ** 2 for i in range(3)) <= ball.radius**2 * (1 + 1e-9)


def effects(scene: Scene, rules: Rules) -> Effects:
    """Derive the effects from materials, light and rules.

    Conservative by construction: an effect is skipped only when it provably adds exactly zero
    to every pixel, so a pruned render is bit-identical to tracing everything (tested).
    """
    mats = [s.material for s in scene.shapes]
    lit = _any(scene.light.color)
    ambient = any(_any(m.ambient) for m in mats)
    diffuse = lit and any(_any(m.diffuse) for m in mats)
    specular = lit and any(_any(m.specular) for m in mats)
    # Shadows matter whenever a lit term exists: even a lone plane blocks its own shadow rays when
    # the light is behind it (one-sided, fixed offset), and a ball shadows its own back.
    shadows = (diffuse or specular) and bool(scene.shapes)
    reflective = [s for s in scene.shapes if _any(s.material.reflection)]
    reflection = scene.max_depth > 0 and bool(reflective)
    depth = 0
    if reflection:
        depth = scene.max_depth
        # With a fixed offset a secondary ray can re-hit its own surface (the offset is below the
        # coordinates' rounding at large scales, or zero), so only the error-bound offset prunes depth.
        if len(reflective) == 1 and rules.offset == "error-bound":
            # A reflected ray leaves its surface and cannot come back to a plane, nor to a ball seen
            # from outside. It could re-hit a ball from inside, when something that starts rays
            # (camera, image plane, another shape) is inside the ball; then keep the full depth.
            (s,) = reflective
            reenter = _ball_reenterable(scene, s, rules) if isinstance(s, Ball) else _plane_reenterable(scene, s, rules)
            if not reenter:
                depth = 1
    background = _any(scene.background)
    return Effects(
        ambient=ambient,
        diffuse=diffuse,
        specular=specular,
        shadows=shadows,
        reflection=reflection,
        reflection_depth=depth,
        background=background,
    )


def _ball_reenterable(scene: Scene, ball: Ball, rules: Rules) -> bool:
    if rules.near_root_only:
        return False  # only the near root counts: a ball is never hit from inside
    cam = scene.camera.position
    corners = [(x, y, 0.0) for x in (-0.5, 0.5) for y in (-0.5, 0.5)]
    if _inside(ball, cam) or any(_inside(ball, c) for c in corners):
        return True
    # Image-plane points between the corners, or other shapes, could lie inside: be conservative.
    cx, cy, cz = ball.center
    near_plane = abs(cz) <= ball.radius and abs(cx) <= 0.5 + ball.radius and abs(cy) <= 0.5 + ball.radius
    return near_plane or len(scene.shapes) > 1


def _plane_reenterable(scene: Scene, plane: Plane, rules: Rules) -> bool:
    # One-sided plane hit from behind with a fixed offset along its (unflipped) normal: the ray is
    # pushed to the front and reflected back through the plane, so it hits the plane again.
    if rules.two_sided or rules.offset == "error-bound":
        return False
    if len(scene.shapes) > 1:
        return True  # another shape could send rays to the back side: be conservative
    n, a = plane.normal, plane.distance
    starts = [scene.camera.position] + [(x, y, 0.0) for x in (-0.5, 0.5) for y in (-0.5, 0.5)]
    return any(sum(n[i] * p[i] for i in range(3)) <= a for p in starts)
