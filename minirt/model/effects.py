"""Which effects a scene under its rules calls for -- the mission's "simulate only the effects a scene calls for".

Shadows, specular, reflection, background, ambient: an effect is simulated only where some shape or
light can produce it (minirt.reference.tracer skips the rest; oracles say what they left out)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from minirt.model.rules import Rules
from minirt.model.scene import Ball, Plane, Scene


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
    shadows = (diffuse or specular) and bool(scene.shapes) and rules.shadow_rays  # rule shadow_rays: a test at all
    reflective = [s for s in scene.shapes if _any(s.material.reflection)]
    reflection = scene.max_depth > 0 and bool(reflective)
    depth = 0
    if reflection:
        depth = scene.max_depth
        # With a fixed offset a secondary ray can re-hit its own surface (the offset is below the
        # coordinates' rounding at large scales, or zero), so only the error-bound offset prunes depth
        # (always along the normal: offset_along applies to numeric offsets only).
        if len(reflective) == 1 and rules.offset == "error-bound":
            # A reflected ray leaves its surface and cannot come back to a plane, nor to a ball seen
            # from outside. It could re-hit a ball from inside, when something that starts rays
            # (camera, image plane, another shape) is inside the ball; then keep the full depth.
            (s,) = reflective
            reenter = _ball_reenterable(scene, s, rules) if isinstance(s, Ball) else _plane_reenterable(scene, s, rules)
            if not reenter:
                depth = 1
    background = _any(scene.background) and rules.background != "none"
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
