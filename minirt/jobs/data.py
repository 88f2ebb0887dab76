"""Results as data: a format that holds dataclasses of NumPy arrays, numbers, strings, dicts and lists, and
whose reading never runs code -- and ``Schema``, what a job's result must be, checked before it is used.

A result is written as one JSON line (its structure) followed by its arrays, each in NumPy's own ``.npy``
format (``numpy.lib.format``), read back with ``allow_pickle=False``: an array of Python objects, the one
kind of ``.npy`` that would unpickle, is refused. In the JSON every value that is not a plain number, string,
list or null is an object with one ``$`` key:

- ``{"$d": [[key, value], ...]}`` a dict, ``{"$t": [...]}`` a tuple, ``{"$b": "base64"}`` bytes,
  ``{"$f": "nan" | "inf" | "-inf"}`` a float JSON cannot write;
- ``{"$a": i}`` the i-th array, ``{"$n": i}`` a NumPy scalar (the i-th array, of shape ());
- ``{"$c": "Name", "f": {field: value, ...}}`` an instance of one of the schema's dataclasses, made by
  calling the class with exactly its fields; ``{"$r": i}`` the i-th instance again (an object held in two
  places is written once and read back as one object).

Reading a crafted file can therefore give wrong data but never run code: classes come only from the
schema's own list, by name, and are only called with their fields. What was read is then checked against
the schema's type (``Schema.check``: every field of every dataclass, every element of every list and
dict, against its annotation), so a file of the right format but the wrong shape is refused, not used.
The same check applies to what a Dask worker hands back (minirt.jobs.batch).

Why not pickle: a pickle runs code when loaded, so a cache folder would have to be as trusted as minirt's
own code. Why not pydantic (a dependency already): it validates, but would still need this encoding for
arrays, tuples, non-finite floats and shared objects; the check here is ~60 lines over ``typing``.
"""

from __future__ import annotations

import base64
import dataclasses
import functools
import io
import json
import math
import types
import typing
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

# ---------------------------------------------------------------------------------------------
# Schema: what a result must be


class JSON:
    """A type for annotations and schemas: JSON-like values, for what ends up in a JSON document -- None,
    booleans, numbers (NumPy's too), strings, and lists, tuples and string-keyed dicts of them."""


@dataclass(frozen=True)
class Schema:
    """A result's type (``hint``: a type expression such as ``tuple[BackendCheck, RenderResult | None]``)
    and the dataclasses it may hold (``classes``: the only ones the reader makes). A TypedDict in the
    hint is checked key by key: its required keys present, no others."""

    hint: Any
    classes: tuple[type, ...] = ()
    by_name: dict[str, type] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        names = {c.__name__: c for c in self.classes}
        if len(names) != len(self.classes) or not all(dataclasses.is_dataclass(c) for c in self.classes):
            raise TypeError("Schema.classes: dataclasses with distinct names")
        object.__setattr__(self, "by_name", names)

    def check(self, value: Any) -> None:
        """Raise ValueError, naming where and what, unless ``value`` is of this schema's type."""
        _check(value, self.hint, "the result", self, set())

    def encode(self, value: Any) -> bytes:
        """The value as data (the module's format); TypeError for what the format cannot hold."""
        self.check(value)
        return _Writer(self).write(value)

    def decode(self, data: bytes) -> Any:
        """The value ``encode`` wrote; ValueError (or another exception, never a code run) for anything else."""
        value = _Reader(self, data).read()
        self.check(value)
        return value


# ---------------------------------------------------------------------------------------------
# The check


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


_NONE = type(None)


def _check(v: Any, hint: Any, where: str, schema: Schema, seen: set[int]) -> None:
    if hint is Any or hint is object:
        return
    if hint is JSON:
        _check_json(v, where)
        return
    if hint is None or hint is _NONE:
        if v is not None:
            raise ValueError(f"{where}: expected None, got {type(v).__name__}")
        return
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        errors = []
        for h in args:
            try:
                _check(v, h, where, schema, seen)
                return
            except ValueError as e:
                errors.append(str(e))
        raise ValueError(errors[0] if len(errors) == 1 else f"{where}: {type(v).__name__} is none of {hint}")
    if origin is typing.Literal:
        if v not in args or type(v) not in {type(a) for a in args}:
            raise ValueError(f"{where}: expected one of {list(args)}, got {_short(v)}")
        return
    if origin in (list, tuple, dict, set, frozenset) or hint in (list, tuple, dict, set, frozenset, bytes, str):
        _check_container(v, origin or hint, args, where, schema, seen)
        return
    if hint is bool:
        if not isinstance(v, bool | np.bool_):
            raise ValueError(f"{where}: expected bool, got {type(v).__name__}")
        return
    if hint is int:
        if isinstance(v, bool | np.bool_) or not isinstance(v, int | np.integer):
            raise ValueError(f"{where}: expected int, got {type(v).__name__}")
        return
    if hint is float:
        if isinstance(v, bool | np.bool_) or not isinstance(v, float | int | np.floating | np.integer):
            raise ValueError(f"{where}: expected float, got {type(v).__name__}")
        return
    if hint is np.ndarray:
        if not isinstance(v, np.ndarray) or v.dtype.hasobject:
            raise ValueError(f"{where}: expected an array of numbers, got {type(v).__name__}")
        return
    if typing.is_typeddict(hint):
        _check_typed_dict(v, hint, where, schema, seen)
        return
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        _check_dataclass(v, hint, where, schema, seen)
        return
    if isinstance(hint, type):
        if not isinstance(v, hint):
            raise ValueError(f"{where}: expected {hint.__name__}, got {type(v).__name__}")
        return
    raise TypeError(f"Schema: cannot check {hint!r}")


def _check_container(v: Any, kind: type, args: tuple, where: str, schema: Schema, seen: set[int]) -> None:
    """``_check`` of a list, tuple, dict, set, frozenset, bytes or str, and of its items (``args``)."""
    if not isinstance(v, kind):
        raise ValueError(f"{where}: expected {kind.__name__}, got {type(v).__name__}")
    if not args:
        return
    if kind is dict:
        for k, x in v.items():
            _check(k, args[0], f"{where} key {_short(k)}", schema, seen)
            _check(x, args[1], f"{where}[{_short(k)}]", schema, seen)
    elif kind is tuple and not (len(args) == 2 and args[1] is Ellipsis):
        if len(v) != len(args):
            raise ValueError(f"{where}: expected {len(args)} items, got {len(v)}")
        for k, (x, h) in enumerate(zip(v, args, strict=True)):
            _check(x, h, f"{where}[{k}]", schema, seen)
    else:
        for k, x in enumerate(v):
            _check(x, args[0], f"{where}[{k}]", schema, seen)


def _check_typed_dict(v: Any, hint: Any, where: str, schema: Schema, seen: set[int]) -> None:
    """``_check`` of a TypedDict: its keys, none missing nor unknown, and each value."""
    if not isinstance(v, dict):
        raise ValueError(f"{where}: expected a dict, got {type(v).__name__}")
    hints = _hints(hint)
    missing = sorted(hint.__required_keys__ - v.keys())
    extra = sorted(str(k) for k in v.keys() - hints.keys())
    if missing or extra:
        said = f"missing {', '.join(missing)}" if missing else f"unknown {', '.join(extra)}"
        raise ValueError(f"{where}: {said}")
    for k, x in v.items():
        _check(x, hints[k], f"{where}[{k!r}]", schema, seen)


def _check_dataclass(v: Any, hint: Any, where: str, schema: Schema, seen: set[int]) -> None:
    """``_check`` of one of the schema's dataclasses: its exact type, then each field (once per object)."""
    if type(v) is not hint:
        raise ValueError(f"{where}: expected {hint.__name__}, got {type(v).__name__}")
    if id(v) in seen:  # an object held in two places: checked once
        return
    seen.add(id(v))
    if schema.by_name.get(hint.__name__) is not hint:
        raise ValueError(f"{where}: {hint.__name__} is not one of the schema's classes")
    hints = _hints(hint)
    for f in dataclasses.fields(hint):
        _check(getattr(v, f.name), hints[f.name], f"{where}.{f.name}", schema, seen)


def check(value: Any, hint: Any, where: str = "the result") -> None:
    """Raise ValueError unless ``value`` is of ``hint`` (``JSON`` for JSON-like data), outside any schema:
    for the fields a schema's classes annotate ``Any`` that a document will hold."""
    _check(value, hint, where, Schema(None), set())


def _check_json(v: Any, where: str, depth: int = 0) -> None:
    if depth > 64:
        raise ValueError(f"{where}: nested too deeply")
    if v is None or isinstance(v, bool | int | float | str | np.bool_ | np.integer | np.floating):
        return
    if isinstance(v, list | tuple):
        for k, x in enumerate(v):
            _check_json(x, f"{where}[{k}]", depth + 1)
        return
    if isinstance(v, dict):
        for k, x in v.items():
            if not isinstance(k, str):
                raise ValueError(f"{where}: a key that is not a string, {_short(k)}")
            _check_json(x, f"{where}[{k!r}]", depth + 1)
        return
    raise ValueError(f"{where}: {type(v).__name__} is not JSON data")


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


# ---------------------------------------------------------------------------------------------
# Writing and reading


class _Writer:
    def __init__(self, schema: Schema):
        self.schema = schema
        self.arrays: list[np.ndarray] = []
        self.array_index: dict[int, int] = {}
        self.objects: dict[int, int] = {}
        self.busy: set[int] = set()
        self.keep: list[Any] = []  # what the indexes' ids refer to stays alive while writing

    def write(self, value: Any) -> bytes:
        tree = self.tree(value)
        head = json.dumps({"arrays": len(self.arrays), "value": tree}, allow_nan=False, separators=(",", ":"))
        out = io.BytesIO()
        out.write(head.encode() + b"\n")
        for a in self.arrays:
            np.lib.format.write_array(out, a, allow_pickle=False)
        return out.getvalue()

    def _array(self, a: np.ndarray) -> int:
        if a.dtype.hasobject:
            raise TypeError("an array of Python objects is not data")
        if id(a) not in self.array_index:
            self.keep.append(a)
            self.array_index[id(a)] = len(self.arrays)
            self.arrays.append(a)
        return self.array_index[id(a)]

    def tree(self, v: Any) -> Any:
        if v is None or isinstance(v, bool | str):
            return v
        if isinstance(v, int) and type(v) is int:
            return v
        if type(v) is float:
            return v if math.isfinite(v) else {"$f": "nan" if math.isnan(v) else "inf" if v > 0 else "-inf"}
        if isinstance(v, np.ndarray):
            return {"$a": self._array(v)}
        if isinstance(v, np.generic):
            return {"$n": self._array(np.asarray(v))}
        if type(v) is list:
            return [self.tree(x) for x in v]
        if type(v) is tuple:
            return {"$t": [self.tree(x) for x in v]}
        if type(v) is dict:
            return {"$d": [[self.tree(k), self.tree(x)] for k, x in v.items()]}
        if type(v) is bytes:
            return {"$b": base64.b64encode(v).decode()}
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            cls = type(v)
            if self.schema.by_name.get(cls.__name__) is not cls:
                raise TypeError(f"{cls.__name__} is not one of the schema's classes")
            if id(v) in self.objects:
                return {"$r": self.objects[id(v)]}
            if id(v) in self.busy:
                raise TypeError(f"a {cls.__name__} that holds itself")
            self.busy.add(id(v))
            fields = {f.name: self.tree(getattr(v, f.name)) for f in dataclasses.fields(v) if f.init}
            self.busy.discard(id(v))
            self.keep.append(v)
            self.objects[id(v)] = len(self.objects)
            return {"$c": cls.__name__, "f": fields}
        raise TypeError(f"{type(v).__name__} is not data (numbers, strings, arrays, lists, dicts, dataclasses)")


class _Reader:
    def __init__(self, schema: Schema, data: bytes):
        self.schema = schema
        self.data = data
        self.arrays: list[np.ndarray] = []
        self.objects: list[Any] = []

    def read(self) -> Any:
        end = self.data.find(b"\n")
        if end < 0:
            raise ValueError("no structure line")
        head = json.loads(self.data[:end].decode("utf-8"))
        if not isinstance(head, dict) or set(head) != {"arrays", "value"} or type(head["arrays"]) is not int:
            raise ValueError("not a result's structure")
        self.arrays = list(_read_arrays(memoryview(self.data)[end + 1 :], head["arrays"]))
        return self.value(head["value"])

    def value(self, t: Any) -> Any:
        if t is None or isinstance(t, bool | str | int | float):
            return t
        if isinstance(t, list):
            return [self.value(x) for x in t]
        if not isinstance(t, dict) or len(t) not in (1, 2):
            raise ValueError("not a tagged value")
        if "$c" in t:
            return self._object(t)
        ((tag, x),) = t.items()
        if tag == "$t" and isinstance(x, list):
            return tuple(self.value(y) for y in x)
        if tag == "$d" and isinstance(x, list):
            out = {}
            for pair in x:
                if not isinstance(pair, list) or len(pair) != 2:
                    raise ValueError("a dict entry is not a pair")
                k = self.value(pair[0])
                if isinstance(k, list | dict | np.ndarray) or k in out:
                    raise ValueError("a dict key that is not one")
                out[k] = self.value(pair[1])
            return out
        if tag == "$b" and isinstance(x, str):
            return base64.b64decode(x, validate=True)
        if tag == "$f" and x in ("nan", "inf", "-inf"):
            return float(x)
        if tag in ("$a", "$n") and type(x) is int and 0 <= x < len(self.arrays):
            a = self.arrays[x]
            if tag == "$a":
                return a
            if a.shape != ():
                raise ValueError("a scalar that is not one")
            return a[()]
        if tag == "$r" and type(x) is int and 0 <= x < len(self.objects) and self.objects[x] is not None:
            return self.objects[x]
        raise ValueError(f"an unknown or malformed tag {tag!r}")

    def _object(self, t: dict) -> Any:
        cls = self.schema.by_name.get(t.get("$c"))  # type: ignore[arg-type]
        f = t.get("f")
        if cls is None or set(t) != {"$c", "f"} or not isinstance(f, dict):
            raise ValueError(f"an unknown class {str(t.get('$c'))[:40]!r}")
        names = {x.name for x in dataclasses.fields(cls) if x.init}
        if set(f) != names:
            raise ValueError(f"{cls.__name__}: fields {sorted(set(f) ^ names)} differ")
        slot = len(self.objects)
        self.objects.append(None)  # this object's index, taken before its fields (as the writer numbers them)
        obj = cls(**{k: self.value(x) for k, x in f.items()})
        self.objects[slot] = obj
        return obj


def _read_arrays(buf: memoryview, count: int) -> Iterable[np.ndarray]:
    """``count`` .npy records from ``buf``: each header is read and checked first (no Python objects, a size
    the bytes left can hold), then the array itself with numpy's own reader, allow_pickle=False."""
    if count < 0:
        raise ValueError("a negative number of arrays")
    f = io.BytesIO(buf)
    for _ in range(count):
        start = f.tell()
        major, _minor = np.lib.format.read_magic(f)
        read_header: Callable | None = {
            1: np.lib.format.read_array_header_1_0, 2: np.lib.format.read_array_header_2_0
        }.get(major)  # fmt: skip
        if read_header is None:
            raise ValueError(f".npy version {major} (this writer writes 1 and 2)")
        shape, _fortran, dtype = read_header(f)
        if dtype.hasobject:
            raise ValueError("an array of Python objects")
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > len(buf) - f.tell():
            raise ValueError("an array larger than the bytes that hold it")
        f.seek(start)
        yield np.lib.format.read_array(f, allow_pickle=False)
    if f.tell() != len(buf):
        raise ValueError("bytes after the last array")
