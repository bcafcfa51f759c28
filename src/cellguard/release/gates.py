"""Gates: a condition on a metric of a stage's runs, ending ``pass``, ``fail`` or ``inconclusive``.

As Argo Rollouts' analysis: a condition against an absolute value (``min`` / ``max``) or against
``last_good``'s figure on the same stage (``max_vs_last_good: 1.05`` = at most 5 % worse), and
``min_cycles``: with less data a gate is inconclusive, never pass. A hard gate (a safety count:
protective stops, limit violations, shadow stops) has a failure limit of 0 and fails on the first
occurrence, however few cycles ran.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field, model_validator

from cellguard.release.errors import GateError
from cellguard.release.evidence import RunEvidence
from cellguard.release.metrics import METRICS, Measure, Metric
from cellguard.yaml_file import yaml_bool_text

PASS, FAIL, INCONCLUSIVE = "pass", "fail", "inconclusive"
NO_DATA = Measure(None, 0)
MAX_MIN_CYCLES = 1_000_000  # more cycles than any stage runs: such a gate could only stay inconclusive


class Gate(BaseModel):
    """One gate of a stage, as declared in the plan's YAML; strict, finite numbers only (``min: .nan`` passed
    every value, ``min: "0.5"`` and ``hard: "yes"`` were taken as meant)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

    metric: str
    min: float | None = None
    max: float | None = None
    min_vs_last_good: float | None = Field(default=None, gt=0.0, description="value >= factor x last_good's")
    max_vs_last_good: float | None = Field(default=None, gt=0.0, description="value <= factor x last_good's")
    min_cycles: int = Field(default=1, ge=1, le=MAX_MIN_CYCLES)
    hard: bool = False

    @model_validator(mode="after")
    def _check(self):
        if self.metric not in METRICS:
            raise ValueError(f"unknown metric {self.metric!r}; known: {', '.join(sorted(METRICS))}")
        if self.is_hard and (self.max != 0 or self.min is not None):
            if not METRICS[self.metric].hard:  # the plan's hard: true, not the metric (it said the metric was hard)
                raise ValueError(f"hard: true makes {self.metric} a hard gate, which fails on any value above 0: "
                                 f"its only limit is max: 0; for another limit leave out hard: true")
            raise ValueError(f"{self.metric} is a hard gate: its failure limit is 0, write max: 0")
        if all(v is None for v in (self.min, self.max, self.min_vs_last_good, self.max_vs_last_good)):
            raise ValueError("no condition: give min, max, min_vs_last_good or max_vs_last_good")
        most = METRICS[self.metric].most
        if self.min is not None and self.min > most:
            raise ValueError(f"min {self.min:g}: {self.metric} is at most {most:g}, no value passes")
        if self.max is not None and self.max < 0:
            raise ValueError(f"max {self.max:g}: {self.metric} is at least 0, no value passes")
        for low, high in ((self.min, self.max), (self.min_vs_last_good, self.max_vs_last_good)):
            if low is not None and high is not None and low > high:
                raise ValueError(f"the lower limit {low:g} is above the upper {high:g}: no value passes")
        return self

    @property
    def is_hard(self) -> bool:
        return self.hard or METRICS[self.metric].hard

    def condition(self) -> str:
        parts = [f">= {self.min:g}" if self.min is not None else "", f"<= {self.max:g}" if self.max is not None else "",
                 f">= {self.min_vs_last_good:g} x last_good" if self.min_vs_last_good else "",
                 f"<= {self.max_vs_last_good:g} x last_good" if self.max_vs_last_good else ""]
        return " and ".join(p for p in parts if p)


@dataclass(frozen=True)
class GateResult:
    metric: str
    status: str  # pass | fail | inconclusive
    value: float | None
    last_good: float | None
    condition: str
    cycles: int
    min_cycles: int
    hard: bool
    detail: str
    evidence: tuple[str, ...]

    def to_dict(self) -> dict:
        return {**self.__dict__, "evidence": list(self.evidence)}


def evaluate(gate: Gate, runs: Sequence[RunEvidence], last_good_runs: Sequence[RunEvidence] = (),
             no_last_good: str = "no last_good on this stage") -> GateResult:
    """The gate's result on ``runs``; ``last_good_runs`` are last_good's runs on the same stage, ``no_last_good``
    why there are none, in words: a relative gate's detail says it (it said "no last_good on this stage" where a
    last_good had only runs of another plan's runs)."""
    metric = METRICS[gate.metric]
    m, wrong = _measured(metric, runs)
    lg_measure, lg_wrong = _measured(metric, last_good_runs) if last_good_runs else (NO_DATA, None)
    lg = lg_measure.value

    def result(status: str, detail: str, measure: Measure = m) -> GateResult:
        return GateResult(gate.metric, status, measure.value, lg, gate.condition(), measure.cycles, gate.min_cycles,
                          gate.is_hard, detail, measure.evidence)

    if wrong:  # no figure to hold against the limit: a hard gate is not shown to be 0
        return result(FAIL if gate.is_hard else INCONCLUSIVE, wrong)
    if m.value is None:
        return result(INCONCLUSIVE, "no data in these runs")
    if gate.is_hard and m.value > 0:
        return result(FAIL, f"{m.value:g} {metric.unit} where the failure limit is 0")
    if m.cycles < gate.min_cycles:
        return result(INCONCLUSIVE, f"{m.cycles} cycles, fewer than min_cycles {gate.min_cycles}")
    broken = []
    if gate.min is not None and m.value < gate.min:
        broken.append(f"{m.value:.4g} < {gate.min:g}")
    if gate.max is not None and m.value > gate.max:
        broken.append(f"{m.value:.4g} > {gate.max:g}")
    relative = gate.min_vs_last_good is not None or gate.max_vs_last_good is not None
    if relative and lg is not None:
        if gate.min_vs_last_good is not None and m.value < gate.min_vs_last_good * lg:
            broken.append(f"{m.value:.4g} < {gate.min_vs_last_good:g} x last_good {lg:.4g}")
        if gate.max_vs_last_good is not None and m.value > gate.max_vs_last_good * lg:
            broken.append(f"{m.value:.4g} > {gate.max_vs_last_good:g} x last_good {lg:.4g}")
    if broken:
        return result(FAIL, "; ".join(broken))
    if relative and lg_wrong:
        return result(INCONCLUSIVE, f"last_good's runs: {lg_wrong}")
    why = "no figure in last_good's runs" if last_good_runs else no_last_good
    if relative and lg is None and gate.min is None and gate.max is None:
        return result(INCONCLUSIVE, f"{why}: nothing to compare with")
    note = f" ({why}: absolute limit only)" if relative and lg is None else ""
    return result(PASS, f"{m.value:.4g} {metric.unit}{note}")


def _measured(metric: Metric, runs: Sequence[RunEvidence]) -> tuple[Measure, str | None]:
    """``metric`` on ``runs``, or no data and what was wrong, in words: it raised, or gave no Measure of a finite
    value, a cycle count and text evidence (a NaN compares false with every limit: it passed every gate, hard ones
    included; a raise left a stage's counted runs without their gates entry)."""
    try:
        m = metric.compute(runs)
    except Exception as exc:  # a metric's own fault is its gate's result, logged with the others
        return NO_DATA, f"{metric.name} raised {type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
    if not isinstance(m, Measure):
        return NO_DATA, f"{metric.name} returned {repr(m)[:80]}, not a Measure"
    if m.value is not None and not (_number(m.value, numbers.Real) and math.isfinite(m.value)):
        return NO_DATA, f"{metric.name} measured {repr(m.value)[:80]}, not a finite number"
    if not (_number(m.cycles, numbers.Integral) and m.cycles >= 0 and isinstance(m.evidence, tuple)
            and all(isinstance(e, str) for e in m.evidence)):
        return NO_DATA, f"{metric.name} returned {repr(m)[:120]}: its cycles are no count or its evidence no text"
    return Measure(None if m.value is None else float(m.value), int(m.cycles), m.evidence), None


def _number(value, kind: type) -> bool:
    """``value`` is of the numbers ``kind`` (numpy's too), not a bool."""
    return isinstance(value, kind) and not isinstance(value, bool)


def verdict(results: Sequence[GateResult]) -> str:
    """fail if any gate failed, else inconclusive if any was, else pass (no gates: inconclusive)."""
    statuses = {r.status for r in results}
    if FAIL in statuses:
        return FAIL
    if INCONCLUSIVE in statuses or not results:
        return INCONCLUSIVE
    return PASS


def gate_error(where: str, exc) -> GateError:
    """A pydantic error on a gate as one line naming it."""
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"])
    msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
    got = err.get("input")
    if isinstance(got, str | bool | int | float) and err["type"] != "extra_forbidden":
        msg += f" (got {got!r}" + _as_text(got, err["type"]) + ")"
    return GateError(f"{where}{'.' + loc if loc else ''}: {msg}")


def _as_text(got, kind: str) -> str:
    """What to write where a number or a boolean was given as text (a quoted number; YAML 1.1's ``yes``, ``off``,
    which the loader reads as text): else nothing."""
    if isinstance(got, str) and kind == "bool_type" and yaml_bool_text(got):
        return ": text to YAML 1.2; write true or false, unquoted"
    if isinstance(got, str) and _number_as_text(got):
        return ": text to YAML; write the number unquoted"
    return ""


def _number_as_text(text: str) -> bool:
    """A number written in quotes (``max: "1e3"``), which YAML reads as text."""
    try:
        float(text)
    except ValueError:
        return False
    return True
