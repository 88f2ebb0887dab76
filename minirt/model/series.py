"""A backend's accuracy knob as the sweep turns it: its settings (``Setting``), the converged render its
error is measured against (``Truth``) and the series of both (``Series``).

Value types of the sweep (minirt.sweep), here in the model because every backend -- the reference and the
oracles, below the sweep -- declares its own series (``Backend.sweep``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from minirt.model.result import RenderResult
from minirt.model.rules import Rules


@dataclass(frozen=True)
class Setting:
    """One turn of a backend's accuracy knob in the sweep (minirt.sweep): one row of its table."""

    value: Any  # the knob's setting, as the sweep's rows record it
    cost: float  # on the series' cost axis (bits, samples per pixel, triangles per ball, ...)
    options: dict[str, Any]  # the backend's render options for it
    label: str  # as a reader names it, in the sweep's answer: "the reference at 16 spp"
    progress: str  # what the progress line says while it renders: "reference 16 spp"
    samples: int | None = None  # the scene's samples per pixel for it (None: the sweep's scene, one sample)


@dataclass(frozen=True)
class Truth:
    """What a series' error is measured against: a converged render, made once per sweep -- by the first
    row that needs it -- and shared by every series of the same backend that names the same ``key``."""

    key: str  # its name in the sweep's document ("reference/1024spp")
    backend: str  # rendered by this backend (its name) ...
    options: dict[str, Any]  # ... with these options
    samples: int | None = None  # the scene's samples per pixel for it (None: the sweep's scene, one sample)
    rules: Rules | None = None  # under these rules (None: the series' own)
    describe: dict[str, Any] = field(default_factory=dict)  # recorded in the sweep's document beside them


# A per-run time of one render: (the time of the render itself, its per-run start-up, the timer's resolution;
# 0: fine-grained). See Series.seconds.
Seconds = Callable[[RenderResult], tuple[float, float, float]]


@dataclass(frozen=True)
class Series:
    """One knob of a backend, swept: its settings, the rules it renders under and what its error is.

    ``error``: "color" (RMSE and friends against the truth's colour), "color_exposure" (the same after
    matching exposure: a physically based renderer's units), "geometry+color" (the reference's own
    precision: geometry and colour against the truth) or "geometry+check" (a geometry-only backend: its
    buffers against the truth's and the harness's own verdict). ``metric``, ``cost`` and ``theory`` are
    what the sweep's document says of the series (its error measure, its cost axis, what theory expects);
    ``knobs`` the values it was built from, under the names the document's ``knobs`` gives them."""

    backend: str  # rendered by this backend (its name)
    knob: str
    settings: tuple[Setting, ...]
    rules: Rules
    truth: Truth
    error: str
    metric: str  # the error the series is read by ("rmse", "t_rel_mean"): its plot, fit and Pareto front
    cost: str  # what the cost axis counts
    theory: str  # how theory expects the error to fall with the cost
    knobs: dict[str, Any] = field(default_factory=dict)
    candidate: bool = True  # may answer "what does an error below the criterion cost" (the sweep's answer)
    fit: bool = True  # fit a slope to it (not to two points, one of them the truth itself)
    level_factor: float | None = None  # the cost's factor per knob step: the fit gives its factor per level
    # (time of the render, per-run start-up, timer resolution) of one result; None: the render's wall clock
    # (minirt.harness.backends.render), no start-up, fine-grained
    seconds: Seconds | None = None

    @property
    def key(self) -> str:
        return f"{self.backend}/{self.knob}"
