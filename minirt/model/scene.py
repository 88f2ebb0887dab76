"""The scene format (TOML) and the scene model: Ball, Plane, Material, Camera, Light, Scene.

Validation is done by pydantic (strict types, unknown keys forbidden, finite numbers only), and
its errors are rewritten into one line per problem: ``scenes/x.toml: shapes[2].radius: must be > 0,
got -1``. Everything after loading works on the frozen dataclasses at the bottom of this file.
"""

from __future__ import annotations

import hashlib
import math
import stat
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from minirt.errors import MinirtError, SceneError
from minirt.model.rules import validate_model_table

Vec3 = tuple[float, float, float]

# Geometry lives within 1e-100 .. 1e100: beyond that, squared lengths (dot products, |p|^2) over- or
# underflow float64, and no intersection formula survives. Colours are not bounded.
LIMIT = 1e100
_Finite = Annotated[float, Field(allow_inf_nan=False, strict=True, ge=-LIMIT, le=LIMIT)]
_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False, strict=True)]
# TOML arrays arrive as lists: the triple itself is lax (list -> tuple), its components stay strict.
_Vec = Annotated[tuple[_Finite, _Finite, _Finite], Field(strict=False)]
_Color = Annotated[tuple[_NonNeg, _NonNeg, _NonNeg], Field(strict=False)]
# A material's colours may be negative: real solutions derive materials that way (a diffuse colour of
# (0.1, -0.9, -0.9)), and grading their images needs the scene they rendered. Said as a warning
# (``colour_warnings``), not refused. Bounded like geometry: beyond 1e100 squared terms overflow.
_Signed = Annotated[float, Field(allow_inf_nan=False, strict=True, ge=-LIMIT, le=LIMIT)]
_SignedColor = Annotated[tuple[_Signed, _Signed, _Signed], Field(strict=False)]


def _at_least_tiny(v: float) -> float:
    # Runs after the `> 0` bound, so a negative value is reported as "must be > 0", the rule a user knows.
    if v < 1 / LIMIT:
        raise ValueError(f"must be >= 1e-100, got {v:g}")
    return v


class _Strict(BaseModel):
    # strict: "1.0" is not a number and true is not 1; ints are still accepted where floats are asked.
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)


class _SceneInfo(_Strict):
    name: str | None = None
    description: str = ""


# The limits of the integer keys, one place for scene files and the CLI's flags (with_overrides):
# OpenEXR's and the PNG writer's practical 16384 per side, 2^16 samples, 64 reflection levels.
LIMITS = {"width": (1, 16384), "height": (1, 16384), "samples": (1, 65536), "max_depth": (0, 64)}


class _Camera(_Strict):
    distance: Annotated[float, Field(gt=0, le=LIMIT, allow_inf_nan=False)]
    width: Annotated[int, Field(ge=LIMITS["width"][0], le=LIMITS["width"][1])] = 256
    height: Annotated[int, Field(ge=LIMITS["height"][0], le=LIMITS["height"][1])] = 256

    @field_validator("distance")
    @classmethod
    def _not_tiny(cls, v: float) -> float:
        return _at_least_tiny(v)


class _Light(_Strict):
    position: _Vec
    color: _Color = (1.0, 1.0, 1.0)


class _Render(_Strict):
    background: _Color = (0.0, 0.0, 0.0)
    max_depth: Annotated[int, Field(ge=LIMITS["max_depth"][0], le=LIMITS["max_depth"][1])] = 3
    samples: Annotated[int, Field(ge=LIMITS["samples"][0], le=LIMITS["samples"][1])] = 1
    profile: str = "exercise"


class _Material(_Strict):
    ambient: _SignedColor = (0.0, 0.0, 0.0)
    diffuse: _SignedColor = (0.0, 0.0, 0.0)
    specular: _SignedColor = (0.0, 0.0, 0.0)
    reflection: _SignedColor = (0.0, 0.0, 0.0)


class _Ball(_Strict):
    type: Literal["ball"]
    center: _Vec
    radius: Annotated[float, Field(gt=0, le=LIMIT, allow_inf_nan=False)]
    material: str

    @field_validator("radius")
    @classmethod
    def _not_tiny(cls, v: float) -> float:
        return _at_least_tiny(v)


class _Plane(_Strict):
    type: Literal["plane"]
    normal: _Vec
    distance: _Finite
    material: str

    @field_validator("normal")
    @classmethod
    def _nonzero(cls, v: Vec3) -> Vec3:
        n = math.sqrt(sum(c * c for c in v))
        if not n > 0:
            raise ValueError(f"must be a non-zero vector, got {list(v)}")
        if not 1 / LIMIT <= n <= LIMIT:
            raise ValueError(f"must have a length within 1e-100 .. 1e100, got {n:g}")
        return v


class _SceneFile(_Strict):
    scene: _SceneInfo = _SceneInfo()
    camera: _Camera
    light: _Light
    render: _Render = _Render()
    model: dict[str, Any] = {}
    materials: dict[str, _Material] = {}
    shapes: list[Annotated[_Ball | _Plane, Field(discriminator="type")]] = []

    @model_validator(mode="after")
    def _materials_exist(self) -> _SceneFile:
        missing = [(i, s.material) for i, s in enumerate(self.shapes) if s.material not in self.materials]
        if missing:
            i, name = missing[0]
            known = ", ".join(sorted(self.materials)) or "none defined"
            raise ValueError(f"shapes[{i}].material: unknown material {name!r} (known: {known})")
        return self


# ---------------------------------------------------------------------------------------------
# The scene model used by everything downstream.


@dataclass(frozen=True)
class Material:
    ambient: Vec3 = (0.0, 0.0, 0.0)
    diffuse: Vec3 = (0.0, 0.0, 0.0)
    specular: Vec3 = (0.0, 0.0, 0.0)
    reflection: Vec3 = (0.0, 0.0, 0.0)
    name: str = ""


@dataclass(frozen=True)
class Ball:
    center: Vec3
    radius: float
    material: Material


@dataclass(frozen=True)
class Plane:
    """All x with dot(x, normal) = distance; stored normalised (normal and distance divided by |normal|)."""

    normal: Vec3
    distance: float
    material: Material
    written: float = 1.0  # |normal| as written in the scene (rule raw_normals: a normal never normalised)

    @property
    def point(self) -> Vec3:
        """The plane's point nearest the origin, Q = distance * normal (the point-normal form)."""
        return (
            self.normal[0] * self.distance,
            self.normal[1] * self.distance,
            self.normal[2] * self.distance,
        )


Shape = Ball | Plane


@dataclass(frozen=True)
class Camera:
    distance: float
    width: int = 256
    height: int = 256

    @property
    def position(self) -> Vec3:
        return (0.0, 0.0, -self.distance)


@dataclass(frozen=True)
class Light:
    position: Vec3
    color: Vec3 = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    camera: Camera
    light: Light
    background: Vec3
    max_depth: int
    samples: int
    profile: str
    model: dict[str, Any]
    shapes: tuple[Shape, ...]
    source: str = ""  # file it came from, for messages
    digest: str = ""  # sha256 of the file's bytes
    materials: dict[str, Material] = field(default_factory=dict)

    def with_overrides(self, **kw: Any) -> Scene:
        """A copy with camera size, samples, profile or max_depth replaced (CLI flags), within the same
        limits as the scene file's keys."""

        for key, (lo, hi) in LIMITS.items():
            v = kw.get(key)
            if v is not None and not lo <= v <= hi:
                raise MinirtError(f"--{key.replace('_', '-')} {v}: must be between {lo} and {hi}")

        cam = self.camera
        if kw.get("width") is not None or kw.get("height") is not None:
            cam = replace(cam, width=kw.get("width") or cam.width, height=kw.get("height") or cam.height)
        out = replace(self, camera=cam)
        for key in ("samples", "profile", "max_depth"):
            if kw.get(key) is not None:
                out = replace(out, **{key: kw[key]})
        return out


def _loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in ("ball", "plane", "tagged-union[_Ball,_Plane]"):
            continue  # pydantic's discriminator step, not a key in the file
        else:
            out += ("." if out else "") + str(part)
    return out


def _message(err: dict[str, Any]) -> str:
    kind, ctx, value = err["type"], err.get("ctx", {}), err.get("input")
    shown = repr(value) if isinstance(value, str) else value
    if isinstance(value, float) and not math.isfinite(value):
        return f"must be a finite number, got {value}"
    if kind == "finite_number":
        return f"must be a finite number, got {shown}"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}[kind]
        bound = next(iter(ctx.values()))
        if isinstance(bound, float):
            bound = int(bound) if bound.is_integer() and abs(bound) < 1e15 else f"{bound:g}"
        return f"must be {op} {bound}, got {shown}"
    if kind == "missing":
        if isinstance(err["loc"][-1], int):
            return "must have 3 components"
        return "missing (required)"
    if kind == "extra_forbidden":
        return "unknown key"
    if kind in ("float_type", "int_type", "string_type", "bool_type", "dict_type", "list_type", "tuple_type"):
        want = {
            "float": "a number",
            "int": "an integer",
            "string": "a string",
            "bool": "true or false",
            "dict": "a table",
            "list": "an array",
            "tuple": "an array of 3 numbers",
        }[kind.split("_")[0]]
        return f"must be {want}, got {type(value).__name__} {shown}"
    if kind in ("too_short", "too_long"):
        return f"must have 3 components, got {shown}"
    if kind == "union_tag_invalid":
        return f"unknown shape type {ctx.get('tag')!r} (expected 'ball' or 'plane')"
    if kind == "union_tag_not_found":
        return "missing key 'type' ('ball' or 'plane')"
    if kind == "value_error":
        return str(ctx.get("error", err["msg"]))
    return err["msg"]


def parse_scene(text: str, source: str = "<scene>") -> Scene:
    """Parse and validate TOML text; raise SceneError with one line per problem."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{source}: TOML syntax error: {e}") from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise SceneError(f"{source}: TOML nested too deeply (no scene key nests more than 3 levels)") from None
    try:
        f = _SceneFile.model_validate(raw)
    except RecursionError:
        raise SceneError(f"{source}: values nested too deeply (no scene key nests more than 3 levels)") from None
    except ValidationError as e:
        lines = []
        for err in e.errors(include_url=False):
            where = _loc(err["loc"])
            msg = _message(err)
            if err["type"] == "value_error" and msg.startswith("shapes["):
                lines.append(f"{source}: {msg}")
            else:
                lines.append(f"{source}: {where}: {msg}" if where else f"{source}: {msg}")
        raise SceneError(*lines) from None

    problems = validate_model_table(f.render.profile, f.model)
    if problems:
        raise SceneError(*(f"{source}: {p}" for p in problems))

    materials = {name: Material(**m.model_dump(), name=name) for name, m in f.materials.items()}
    shapes: list[Shape] = []
    for s in f.shapes:
        if isinstance(s, _Ball):
            shapes.append(Ball(center=s.center, radius=float(s.radius), material=materials[s.material]))
        else:
            n = math.sqrt(sum(c * c for c in s.normal))
            shapes.append(
                Plane(
                    normal=(s.normal[0] / n, s.normal[1] / n, s.normal[2] / n),
                    distance=s.distance / n,
                    material=materials[s.material],
                    written=n,
                )
            )
    name = f.scene.name or Path(source).stem
    return Scene(
        name=name,
        description=f.scene.description,
        camera=Camera(distance=float(f.camera.distance), width=f.camera.width, height=f.camera.height),
        light=Light(position=_floats(f.light.position), color=_floats(f.light.color)),
        background=_floats(f.render.background),
        max_depth=f.render.max_depth,
        samples=f.render.samples,
        profile=f.render.profile,
        model=dict(f.model),
        shapes=tuple(shapes),
        source=source,
        digest=hashlib.sha256(text.encode()).hexdigest(),
        materials=materials,
    )


def _floats(v: tuple[float, ...]) -> Vec3:
    return (float(v[0]), float(v[1]), float(v[2]))


# 256 MiB: room for a scene of a million balls (about 100 MB of TOML); a larger file is a mistake
MAX_SCENE_BYTES = 256 * 2**20


def colour_warnings(scene: Scene) -> list[str]:
    """One line per material with a negative colour component (allowed: see ``_SignedColor``)."""
    out, seen = [], set()
    for k, shape in enumerate(scene.shapes):
        m = shape.material
        if id(m) in seen:
            continue
        seen.add(id(m))
        bad = [f"{term} {list(getattr(m, term))}" for term in ("ambient", "diffuse", "specular", "reflection")
               if any(c < 0 for c in getattr(m, term))]  # fmt: skip
        if bad:
            out.append(
                f"material {m.name or f'of shape {k}'!r} has negative colour components ({'; '.join(bad)}): "
                "drawn as given, as a student's tracer would"
            )
    return out


def load_scene(path: str | Path) -> Scene:
    """Read a scene file. Errors (missing file, syntax, validation) raise SceneError."""
    p = Path(path)
    try:
        st = p.stat()
        if stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError
        if not stat.S_ISREG(st.st_mode):  # a FIFO or a device would block or never end
            raise SceneError(f"{p}: not a regular file (a scene is a TOML file)")
        if st.st_size > MAX_SCENE_BYTES:
            raise SceneError(f"{p}: {st.st_size} bytes, more than a scene may have ({MAX_SCENE_BYTES})")
        data = p.read_bytes()
    except FileNotFoundError:
        if p.is_symlink():
            raise SceneError(f"{p}: a broken symbolic link (what it points to does not exist)") from None
        raise SceneError(f"{p}: no such scene file") from None
    except IsADirectoryError:
        raise SceneError(f"{p}: is a directory, not a scene file") from None
    except OSError as e:
        raise SceneError(f"{p}: cannot read: {e.strerror}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SceneError(f"{p}: not UTF-8 text (byte {e.start})") from None
    return parse_scene(text, str(p))
