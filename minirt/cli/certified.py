"""``minirt probe --certified``: a pixel's certified values -- the exact model's ray tree, from the certified
oracle the registry has (minirt.harness.judge finds it by capability) -- beside the reference's."""

from __future__ import annotations

from typing import Any

from minirt.cli.console import out
from minirt.errors import MinirtError
from minirt.io.untrusted import terminal_text
from minirt.model.rules import Rules
from minirt.model.scene import Scene


def certified_probe(scene: Scene, rules: Rules, x: int, y: int) -> dict[str, Any]:
    from minirt.harness import backends, judge

    name = judge.certified_oracle()
    if name is None:
        raise MinirtError("--certified: no certified oracle is available (minirt doctor)")
    return backends.get(name).probe(scene, rules, x, y)


def _fmt(v) -> str:
    if isinstance(v, list):
        return "(" + ", ".join(f"{c:.9g}" for c in v) + ")"
    return f"{v:.12g}" if isinstance(v, float) else str(v)


def print_certified(c: dict[str, Any]) -> None:
    """--certified: the exact model's ray tree beside the reference's (minirt.harness.judge's oracle)."""
    how = f"exact tie: {c['tie']}" if c["tie"] else f"certified at {c['bits']} bits"
    out.print(f"certified ({terminal_text(c['backend'])}, {how}):", markup=False)
    for lvl in c["levels"]:
        ind = "  " * (lvl["depth"] + 1)
        hit = lvl["hit"]
        if hit is None:
            out.print(f"{ind}level {lvl['depth']}: no hit")
            continue
        lo, hi = hit["t_interval"]
        at = f"shape {hit['id']} at t = {_fmt(hit['t'])} (in [{lo!r}, {hi!r}])"
        out.print(f"{ind}level {lvl['depth']}: {at}, normal {_fmt(hit['normal'])}, lit {lvl['lit']}", markup=False)
    robust = "robust" if c["robust"] else "not robust: the reference's rounding may flip a decision here"
    out.print(f"  colour {_fmt(c['color'])} (+- {c['color_radius']:.2g}); {robust}", markup=False)
