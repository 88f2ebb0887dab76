"""The model rules: where the exercise's pseudo-code and established renderers disagree.

Each difference is a named rule. Profile ``exercise`` takes the pseudo-code's literal reading,
profile ``conventional`` what POV-Ray does, profile ``eth2014`` the same course's 2014 edition of the
exercise. A scene's ``[model]`` table (or ``--rule NAME=VALUE``) overrides single rules. This module
leaves the *effects* a scene needs to minirt.model.effects.

Trace rules (``TRACE_RULES``) change what is traced:

| rule              | exercise (literal)            | conventional                       | eth2014           |
|-------------------|-------------------------------|------------------------------------|-------------------|
| background        | "on-hit" (added at each hit)  | "on-miss" (a miss returns it)      | "none" (never)    |
| near_root_only    | true (ball invisible inside)  | false (nearest root with t > 0)    | false             |
| shadow_range      | "any" (anything on the ray)   | "to-light" (only before the light) | "to-light"        |
| two_sided         | false (normals as given)      | true (normals face the ray)        | false             |
| clamp             | false (s·n, (r·s)^e raw)      | true (max(0, s·n); spec. if s·n>0) | "specular" (1)    |
| offset            | 1e-6 (hit + offset·normal)    | "error-bound" (pbrt-style) (3)     | 1e-3              |
| offset_along      | "normal"                      | "normal"                           | "ray" (2)         |
| ray_origin        | "image-plane"                 | "image-plane" (or "camera")        | "camera"          |
| pixel_sample      | "corner"                      | "corner" (or "center")             | "center"          |
| specular_exponent | 8                             | 8                                  | 16                |
| pixel_shift       | (0, 0) (pixels)               | (0, 0)                             | (0, 0)            |
| t_max             | inf (every hit counts)        | inf                                | inf               |
| raw_normals_ball  | "none" (unit normals)         | "none"                             | "none"            |
| raw_normals_plane | "none"                        | "none"                             | "none"            |
| shadow_rays       | true (a shadow test)          | true                               | true              |
| ball_normal       | "outward" ((p - c) / r)       | "outward"                          | "outward"         |
| light             | "position" (s = (L - p)/|L-p|)| "position"                         | "position"        |
| hit_point         | "ray" (o + t d)               | "ray"                              | "ray"             |
| specular_s        | "s" ((r·s)^e)                 | "s"                                | "s"               |

(1) s·n raw, the specular term only where r·s > 0. (2) hit + offset·(the new ray's direction).
(3) Offset by the hit point's error bound on the side the new ray leaves to -- except from a ball under
near_root_only = true, where secondary rays always start outside the ball: started inside (a shadow ray
from a point facing away from the light), near_root_only would not see the ball and every back-face
self-shadow would be lost; outside, the ball blocks, as under a numeric offset along the normal.

The rules from ``t_max`` on come from bugs seen in real solutions rather than from a reading of the
exercise (``BUG_RULES``; their defaults are the exercise's reading, no oracle follows them, and ``grade``
finds their values from a student's image). Each names the code it models:

- ``t_max`` -- a public C++ solution of this exercise (its bitmap.cpp and vector3.cpp, Ray, Ball, Plane,
  Scene) whose ``Scene::TraceRay`` starts its closest-hit search at ``double t = 30000;`` (pixel units):
  hits of camera and reflected rays beyond it are ignored, and the far part of a ground plane turns to
  background at the horizon. Shadow rays keep the shadow_range rule (the light is nearer than any such
  cut-off in the scenes where it shows).
- ``raw_normals_ball``, ``raw_normals_plane`` -- the same solution's ``Ball::getNormal`` returns
  ``at - middle`` (p - c, not divided by the radius; the exercise's Appendix 2 gives (p - c) / r) and its
  ``Plane::getNormal`` the normal as written in the scene (the exercise stores a plane as (n, a) without
  saying n is of unit length). Real code keeps the two kinds apart -- a solution may normalise one and not
  the other -- and uses the normal twice: "shading", in the diffuse term s·n; "reflection", in the
  reflected direction r = d - 2 (d·n) n (the highlight's r·s uses that r as computed; the reflected ray's
  direction is r normalised, as that solution's Ray normalises its direction); "both". The secondary
  rays' offset stays along the unit normal. ``raw_normals = VALUE`` in a scene's [model] or ``--rule``
  sets both (the one rule of earlier versions).
- ``shadow_rays`` false -- a 2013 solution whose shadow test reads ``if (t = MAX)`` (an assignment, always
  true): no point is ever in shadow; every hit gets its diffuse and specular terms.
- ``ball_normal`` "inward" -- the same solution's ball normal is ``center - p``: c - p, pointing into the
  ball. The diffuse term s·n changes sign; the reflected direction does not (n appears twice); the
  secondary rays' offset ("a small fraction of normal") moves them into the ball.
- ``light`` "direction" -- the same solution uses the light's position as the direction towards it:
  s = L / |L| at every point, not (L - p) / |L - p|. The shadow ray leaves along that s; under
  shadow_range "to-light" it is still cut at the light's distance |L - p|.
- ``hit_point`` "origin" -- the same solution computes the hit point as ``t * d``, without the ray's
  start: p = t d for every ray (the camera's, from the image plane, and the reflected ones). The normal,
  the light direction and the secondary rays' start are computed from that p.
- ``specular_s`` "-s" -- a solution whose highlight uses the direction from the light to the point
  (the incoming light's direction, -s) where the exercise takes s: (r·(-s))^e.

Output rules (``OUTPUT_RULES``) say how the 8-bit bitmap is written; the tracer ignores them (see
minirt.model.bitmap): ``encoding`` "round" (floor(c·255 + 0.5); eth2014: "floor256", min(255,
floor(256·c))), ``gamma`` "linear", ``rows`` "top-down", ``channels`` "rgb", ``transpose`` false.
"""

from __future__ import annotations

import functools
import math
import operator
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any, Protocol

from minirt.errors import MinirtError


class Modelled(Protocol):
    """What ``resolve`` reads of a scene (minirt.model.scene.Scene): its profile's name and its [model]
    table of rules. A protocol, so that the rules need not import the scene, which imports them."""

    @property
    def profile(self) -> str: ...

    @property
    def model(self) -> Mapping[str, Any]: ...


@dataclass(frozen=True)
class Rules:
    background: str = "on-hit"
    near_root_only: bool = True
    shadow_range: str = "any"
    two_sided: bool = False
    clamp: bool | str = False
    offset: float | str = 1e-6
    ray_origin: str = "image-plane"
    pixel_sample: str = "corner"
    specular_exponent: int = 8
    offset_along: str = "normal"
    pixel_shift: tuple[float, float] = (0.0, 0.0)
    t_max: float = math.inf
    raw_normals_ball: str = "none"
    raw_normals_plane: str = "none"
    shadow_rays: bool = True
    ball_normal: str = "outward"
    light: str = "position"
    hit_point: str = "ray"
    specular_s: str = "s"
    # Output rules: how the bitmap is written (minirt.model.bitmap); the tracer ignores them.
    encoding: str = "round"
    gamma: str = "linear"
    rows: str = "top-down"
    channels: str = "rgb"
    transpose: bool = False

    def as_dict(self) -> dict[str, Any]:
        """Every rule by name -- except the rules from real solutions' bugs (``QUIET_AT_DEFAULT``) at their
        defaults: documents written before those rules existed stay what they were, byte for byte (and
        t_max's default, inf, is no JSON number). A new dict each call, made from one kept per rule set: the
        rule diagnosis validates thousands of candidate rule sets (dataclasses.asdict cost ~70 us each)."""
        return dict(_as_dict(self))

    def differs(self, other: Rules) -> list[str]:
        """Names of the rules whose values differ between self and other (in the fields' order)."""
        a, b = self.__dict__, other.__dict__  # a diagnosis asks this ~7,000 times: no fields() each time
        return [name for name in _NAMES if a[name] != b[name]]

    def traced(self) -> Rules:
        """These rules with every output rule at its default: what a render depends on (its cache key). Made
        once per rule set (``_traced``; itself where they are at their defaults already): a diagnosis asks it
        ~10,000 times, and ``replace`` costs ~50 us."""
        if output_rules_of(self) == _OUTPUT_DEFAULTS:
            return self
        return _traced(self)


# The rules from real solutions' bugs (see the module's docstring): no oracle follows them
# (``minirt.model.backend.Backend.adapt``), and documents leave them out at their defaults.
BUG_RULES: tuple[str, ...] = (
    "t_max",
    "raw_normals_ball",
    "raw_normals_plane",
    "shadow_rays",
    "ball_normal",
    "light",
    "hit_point",
    "specular_s",
)
# The rules that change what is traced (below: the ones that only say how the bitmap is written).
TRACE_RULES: tuple[str, ...] = (
    "background",
    "near_root_only",
    "shadow_range",
    "two_sided",
    "clamp",
    "offset",
    "offset_along",
    "ray_origin",
    "pixel_sample",
    "specular_exponent",
    "pixel_shift",
    *BUG_RULES,
)
QUIET_AT_DEFAULT: tuple[str, ...] = BUG_RULES
# Names a scene's [model] or --rule may use for several rules at once: raw_normals sets both kinds.
ALIASES: dict[str, tuple[str, ...]] = {"raw_normals": ("raw_normals_ball", "raw_normals_plane")}
OUTPUT_RULES: tuple[str, ...] = ("encoding", "gamma", "rows", "channels", "transpose")
_DEFAULTS: dict[str, Any] = {f.name: f.default for f in fields(Rules)}
_NAMES: tuple[str, ...] = tuple(_DEFAULTS)  # the fields' names, in their order
_OUTPUT_DEFAULTS = tuple(_DEFAULTS[name] for name in OUTPUT_RULES)
output_rules_of = operator.attrgetter(*OUTPUT_RULES)  # a rule set's output rules as a tuple, in one C call

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
    # The same course's 2014 edition: rays from the camera through pixel centres, smallest positive
    # root, shadows only before the light, diffuse unclamped, (r·s)^16 only where r·s > 0, no
    # background, secondary rays offset 1/1000 along their own direction, min(255, floor(256·c)).
    "eth2014": Rules(
        background="none",
        near_root_only=False,
        shadow_range="to-light",
        two_sided=False,
        clamp="specular",
        offset=1e-3,
        offset_along="ray",
        ray_origin="camera",
        pixel_sample="center",
        specular_exponent=16,
        encoding="floor256",
    ),
}

SPECULAR_EXPONENT_MAX = 1024
T_MAX_FLIP = 10.0  # t_max's flip (``flipped``): inside the bundled scenes, whose far planes lie beyond it
PIXEL_SHIFT_MAX = 4.0

# The values each rule accepts; used for validation and for the CLI's help.
CHOICES: dict[str, tuple[Any, ...]] = {
    "background": ("on-hit", "on-miss", "none"),
    "near_root_only": (True, False),
    "shadow_range": ("any", "to-light"),
    "two_sided": (True, False),
    "clamp": (True, False, "specular"),
    "offset": ("error-bound", "<a number >= 0>"),
    "offset_along": ("normal", "ray"),
    "ray_origin": ("image-plane", "camera"),
    "pixel_sample": ("corner", "center"),
    "specular_exponent": (f"<an integer 1..{SPECULAR_EXPONENT_MAX}>",),
    "pixel_shift": (f'<"dx,dy" in pixels, |d| <= {PIXEL_SHIFT_MAX:g}>',),
    "t_max": ("<a number > 0, or inf>",),
    "raw_normals_ball": ("none", "shading", "reflection", "both"),
    "raw_normals_plane": ("none", "shading", "reflection", "both"),
    "shadow_rays": (True, False),
    "ball_normal": ("outward", "inward"),
    "light": ("position", "direction"),
    "hit_point": ("ray", "origin"),
    "specular_s": ("s", "-s"),
    "encoding": ("round", "floor256", "floor"),
    "gamma": ("linear", "srgb", "2.2"),
    "rows": ("top-down", "bottom-up"),
    "channels": ("rgb", "bgr"),
    "transpose": (False, True),
}

# Candidate values of each rule, for searches over the rule space (every one valid on its own; the
# one cross-rule constraint is offset_along = "ray" needing a numeric offset).
_VALUES: dict[str, tuple[Any, ...]] = {
    "offset": (1e-6, 1e-3, 0.0, "error-bound"),
    "specular_exponent": (1, 2, 4, 8, 16, 32, 64, 128),
    "pixel_shift": ((0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0), (0.5, 0.5)),
    # A diagnosis finds t_max's value from the image (minirt.diagnose.search), not from this list
    "t_max": (math.inf, T_MAX_FLIP),
}


def default(name: str) -> Any:
    """The exercise's value of one rule (the field's default)."""
    return _DEFAULTS[name]


def values(name: str) -> tuple[Any, ...]:
    """The candidate values of one rule (for searches and tests), the default among them."""
    if name not in CHOICES:
        raise KeyError(f"unknown rule {name!r} (known: {', '.join(CHOICES)})")
    return _VALUES.get(name, CHOICES[name])


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _parse_shift(value: Any) -> tuple[float, float] | None:
    """A pixel shift as two floats, from a 2-sequence of numbers or the string "dx,dy"; None if neither."""
    if isinstance(value, str):
        parts = value.split(",")
        if len(parts) != 2:
            return None
        try:
            return float(parts[0].strip()), float(parts[1].strip())
        except ValueError:
            return None
    if isinstance(value, list | tuple) and len(value) == 2 and all(_is_number(c) for c in value):
        return float(value[0]), float(value[1])
    return None


def _check_value(name: str, value: Any) -> str | None:
    if name == "offset":
        if value == "error-bound":
            return None
        if _is_number(value):
            if math.isfinite(value) and value >= 0:
                return None
            return f"model.offset: must be a finite number >= 0 or 'error-bound', got {value}"
        return f"model.offset: must be a number >= 0 or 'error-bound', got {value!r}"
    if name == "specular_exponent":
        ok = _is_number(value) and math.isfinite(value) and value == int(value)
        if ok and 1 <= value <= SPECULAR_EXPONENT_MAX:
            return None
        shown = value if _is_number(value) else repr(value)
        return f"model.specular_exponent: must be an integer from 1 to {SPECULAR_EXPONENT_MAX}, got {shown}"
    if name == "pixel_shift":
        shift = _parse_shift(value)
        if shift is None:
            return f'model.pixel_shift: must be two numbers, [dx, dy] or "dx,dy" (pixels), got {value!r}'
        if not all(math.isfinite(c) and abs(c) <= PIXEL_SHIFT_MAX for c in shift):
            m = f"{PIXEL_SHIFT_MAX:g}"
            return f"model.pixel_shift: each part must be a finite number from -{m} to {m}, got {value!r}"
        return None
    if name == "t_max":
        if _is_number(value) and value > 0 and not math.isnan(value):
            return None
        if value == "inf":
            return None
        return f"model.t_max: must be a number > 0 (or inf), got {value!r}"
    if name == "gamma" and _is_number(value) and value == 2.2:
        return None  # --rule gamma=2.2 arrives as a number
    allowed = CHOICES[name]
    if all(isinstance(a, bool) for a in allowed):
        if not isinstance(value, bool):
            return f"model.{name}: must be true or false, got {value!r}"
        return None
    # Exact type and value: 1.0 == True in Python, and must not pass for clamp = true.
    if not any(type(value) is type(a) and value == a for a in allowed):
        shown = ", ".join("true" if a is True else "false" if a is False else repr(a) for a in allowed)
        return f"model.{name}: must be one of {shown}, got {value!r}"
    return None


def _check_together(rules: dict[str, Any]) -> list[str]:
    """Constraints between rules, on the effective values (profile, then overrides)."""
    if rules.get("offset_along") == "ray" and rules.get("offset") == "error-bound":
        return ['model.offset_along: "ray" needs a numeric offset, got offset = "error-bound"']
    return []


@functools.lru_cache(maxsize=4096)
def _traced(rules: Rules) -> Rules:
    return replace(rules, **{name: _DEFAULTS[name] for name in OUTPUT_RULES})


@functools.lru_cache(maxsize=4096)
def _as_dict(rules: Rules) -> dict[str, Any]:
    # asdict's dict, without its deep copies: every rule is a str, number, bool or a tuple of floats
    d = {name: getattr(rules, name) for name in _NAMES}
    for name in QUIET_AT_DEFAULT:
        if d[name] == _DEFAULTS[name]:
            del d[name]
    return d


def expand_aliases(model: dict[str, Any]) -> dict[str, Any]:
    """A [model] table or --rule overrides with every alias (``ALIASES``) replaced by the rules it sets, in
    place (a rule given by its own name as well wins over the alias)."""
    if not any(name in ALIASES for name in model):
        return model
    out: dict[str, Any] = {}
    for name, value in model.items():
        if name in ALIASES:
            for target in ALIASES[name]:
                out.setdefault(target, value)
        else:
            out[name] = value
    return out


def validate_model_table(profile: str, model: dict[str, Any]) -> list[str]:
    """Problems with a scene's profile name and [model] overrides, one line each (empty if fine)."""
    problems = []
    model = expand_aliases(model)
    if profile not in PROFILES:
        problems.append(f"render.profile: unknown profile {profile!r} (known: {', '.join(PROFILES)})")
    for name, value in model.items():
        if name not in CHOICES:
            problems.append(f"model.{name}: unknown rule (known: {', '.join(CHOICES)})")
            continue
        p = _check_value(name, value)
        if p:
            problems.append(p)
    if not problems:
        problems += _check_together({**PROFILES[profile].as_dict(), **model})
    return problems


def _normalise(name: str, value: Any) -> Any:
    """A valid value in the form Rules holds: floats for offsets and shifts, ints for exponents."""
    if name == "offset" and _is_number(value):
        return float(value)
    if name == "t_max":
        return math.inf if value == "inf" else float(value)
    if name == "specular_exponent":
        return int(value)
    if name == "pixel_shift":
        dx, dy = _parse_shift(value)  # type: ignore[misc]
        return (dx + 0.0, dy + 0.0)  # -0.0 -> 0.0: a zero shift is the default, bit for bit
    if name == "gamma" and _is_number(value):
        return "2.2"
    return value


def resolve(scene: Modelled, profile: str | None = None, overrides: dict[str, Any] | None = None) -> Rules:
    """The rules for a render: the profile (scene's, unless given), then the scene's [model], then overrides."""
    name = profile or scene.profile
    if name not in PROFILES:
        raise MinirtError(f"unknown profile {name!r} (known: {', '.join(PROFILES)})")
    rules = PROFILES[name]
    merged = {**expand_aliases(scene.model), **expand_aliases(overrides or {})}
    problems = validate_model_table(name, merged)
    if problems:
        raise MinirtError(*problems)
    return replace(rules, **{k: _normalise(k, v) for k, v in merged.items()})


def format_rule_value(name: str, value: Any) -> str:
    """The VALUE of ``--rule NAME=VALUE`` that gives this value (round-trips through the CLI's parsing
    and resolve): true/false, floats by repr, ints as ints, a pixel shift as "dx,dy"."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if name == "pixel_shift":
        return ",".join(_short(float(c)) for c in value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _short(x: float) -> str:
    s = f"{x:g}"
    return s if float(s) == x else repr(x)


def flipped(rules: Rules, name: str) -> Rules:
    """The rules with one rule switched to another value (for attribution and tests), deterministically.

    The first two values in CHOICES swap (for the original two-valued rules, as they always did) and a
    later value goes to the first (clamp "specular" -> true, background "none" -> "on-hit": the values
    that differ most, where "on-miss" and "none" look alike whenever every ray hits); offset swaps a
    number and "error-bound" (under offset_along = "ray", which needs a number, 1e-3 and 1e-6 swap
    instead); specular_exponent 8 <-> 16 (anything else -> 8); pixel_shift (0, 0) <-> (1, 0) (anything
    else -> (0, 0)); t_max inf <-> ``T_MAX_FLIP`` (anything else -> inf). offset_along "normal" -> "ray"
    under offset = "error-bound" also sets offset to 1e-3, the one case where a flip changes two rules:
    "ray" needs a numeric offset.
    """
    current = getattr(rules, name)
    if name == "offset":
        if rules.offset_along == "ray":
            return replace(rules, offset=1e-6 if current == 1e-3 else 1e-3)
        return replace(rules, offset=1e-6 if current == "error-bound" else "error-bound")
    if name == "offset_along":
        if current == "normal":
            return replace(rules, offset_along="ray", offset=1e-3 if rules.offset == "error-bound" else rules.offset)
        return replace(rules, offset_along="normal")
    if name == "specular_exponent":
        return replace(rules, specular_exponent=16 if current == 8 else 8)
    if name == "pixel_shift":
        return replace(rules, pixel_shift=(1.0, 0.0) if current == (0.0, 0.0) else (0.0, 0.0))
    if name == "t_max":
        return replace(rules, t_max=T_MAX_FLIP if current == math.inf else math.inf)
    first, second = CHOICES[name][:2]
    is_first = type(current) is type(first) and current == first
    return replace(rules, **{name: second if is_first else first})
