"""Campaign specs (YAML or TOML): families, swept parameters, seeds, what to record.

A spec is a mapping::

    name: smoke                 # campaign name (letters, digits, - _ .)
    seed: 0                     # seeds the draws of random parameters
    batch: auto                 # episodes per Dask task (auto, or an integer >= 1)
    record:
      check_relaxed: false      # independent SLSQP check of every relaxed step (random families)
      step_times: false         # keep every step's wall time in the records (else a histogram)
    sweeps:
      - name: si                # unique per spec
        family: random_si       # paper | random_si | random_bicycle | drive
        seeds: 10               # per point: 10 -> 0..9; {start: 100, count: 10}; or a list [1, 5, 9]
        random_points: 4        # draws of the random parameters (needed when there are any)
        params:
          max_pedestrians: 6                 # a plain value (scalar or list) is fixed
          horizon: {values: [4, 7, 15]}      # explicit list: a grid axis
          delta: {linspace: [0.04, 0.12, 3]} # evenly spaced grid axis (lo, hi, count)
          gamma_ini: {uniform: [0.01, 0.05]} # random range (per random point)
          trust: {choice: [0.2, 0.8]}        # random choice (per random point)

Points of a sweep are the Cartesian product of its grid axes, times ``random_points`` joint
draws of its random parameters (none: one draw of nothing). Every point runs the same seeds, so
points are compared on the same worlds wherever the family allows (common random numbers).
Validation errors name the field (``sweeps[0].params.horizon``) and the expected form.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import tomllib
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from trustnav.schema import (
    Dotted,
    Either,
    Flag,
    Integer,
    Invalid,
    Maybe,
    Number,
    OneOf,
    Rule,
    SchemaError,
    Seq,
    Text,
    bad,
    check_fields,
    check_keys,
    load,
    rules_of,
)

__all__ = [
    "FAMILIES",
    "PARAMS",
    "CampaignSpec",
    "EpisodeTask",
    "RecordOptions",
    "SpecError",
    "SweepPoint",
    "SweepSpec",
    "load_spec",
    "spec_from_dict",
]

FAMILIES = ("paper", "random_si", "random_bicycle", "drive")
_NAME = Text(pattern=r"[A-Za-z0-9_.-]+", what="a name of letters, digits, '-', '_' or '.'")


class SpecError(SchemaError):
    """A campaign spec that does not validate; one line per error, naming the field and the expected form."""


# ----------------------------------------------------------------------------------------------
# parameter rules (trustnav.schema): value -> normalised value, or Invalid with the expected form


def _num(lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False, what: str = "") -> Number:
    return Number(lo, hi, lo_open=lo_open, note=what, cast=True)


def _int_ge(lo: int) -> Integer:
    return Integer(lo, whole_floats=True)


def _scenario(names: tuple[str, ...]) -> Rule:
    return Either(OneOf(*names), Text(pattern=r".+\.toml", what="a path to a .toml scenario"))


def _optional(inner: Rule, none_means: str) -> Maybe:
    return Maybe(inner, none_means, none="null")


def _float_list(lo: float, hi: float) -> Seq:
    return Seq(Number(lo, hi, cast=True), min_len=1, kind=list, what=f"a non-empty list of numbers in [{lo:g}, {hi:g}]")


def _pair_in(lo: float, hi: float) -> Seq:
    what = f"a pair [low, high] with {lo:g} <= low <= high <= {hi:g}"
    return Seq(Number(lo, hi, cast=True), min_len=2, max_len=2, ascending=True, kind=list, what=what)


_GAMMA = {
    "gamma_ini": _num(0.0, 1.0, lo_open=True, what=" (gamma_ini of `weight`)"),
    "delta": _num(0.0, 1.0, lo_open=True, what=" (delta of `weight`)"),
    "lam": _num(1.0, what=" (lambda of `weight`)"),
}
_TIMING = OneOf("paper", "authors_code")
_DEADLINE = _optional(_num(0.0, 3600.0, lo_open=True, what=" s"), "the controller's default dt/2, wall clock")
_RANDOM_PARAMS: dict[str, Rule] = {
    # distribution of worlds (RandomWorldSpec): changes which worlds a seed gives
    "max_pedestrians": _int_ge(1),
    "close_start_share": _num(0.0, 1.0),
    "max_steps": _int_ge(1),
    # applied to the sampled world (same seed, same placements: paired across points)
    "horizon": _int_ge(1),
    "v_max": _num(0.0, lo_open=True, what=" m/s"),
    "trust": _num(0.0, 1.0),
    "trust_range": _pair_in(0.0, 1.0),
    "timing": _TIMING,
    "deadline": _DEADLINE,
    **_GAMMA,
}

#: Parameters each family accepts, with their checkers (the expected form is in the error).
PARAMS: dict[str, dict[str, Rule]] = {
    "paper": {
        "scenario": _scenario(("paper-1", "paper-2", "paper-3")),
        "horizon": _int_ge(1),
        "trust": _num(0.0, 1.0),
        "trusts": _float_list(0.0, 1.0),
        "timing": _TIMING,
        "solver": OneOf("sqp", "slsqp"),
        "reference_v_max": _num(0.0, lo_open=True, what=" m/s"),
        "reference_gain": _num(0.0, lo_open=True),
        "position_jitter": _num(0.0, what=" m (sigma of the pedestrians' start positions, from the seed)"),
        "deadline": _DEADLINE,
        **_GAMMA,
    },
    "random_si": dict(_RANDOM_PARAMS),
    "random_bicycle": dict(_RANDOM_PARAMS),
    "drive": {
        "scenario": _scenario(("case-1", "case-2")),
        "attentive": _optional(Flag(), "as in the scenario"),
        "capture_rate": _num(0.0, 1000.0, lo_open=True, what=" frames/s"),
        "control_rate": _num(0.0, 1000.0, lo_open=True, what=" Hz"),
        "horizon": _int_ge(1),
        "safety_radius": _num(0.0, 100.0, lo_open=True, what=" m"),
        "pixel_noise": _num(0.0, 1.0),
        "dropout": _num(0.0, 0.99),
        "miss_rate": _num(0.0, 0.99),
        "position_noise": _num(0.0, 100.0, what=" m"),
        "velocity_noise": _num(0.0, 100.0, what=" m/s"),
        "deadline": _num(0.0, 3600.0, lo_open=True, what=" s"),
        "state": OneOf("perceived", "true"),
        "pitch_sigma_deg": _num(0.0, 20.0, what=" deg"),
        # the bound is sim.driving.world.MAX_PERCEPTION_LATENCY, not imported here (specs load without the simulator)
        "perception_latency": _num(0.0, 5.0, what=" s (capture to the controller's estimates)"),
        "confidence": _num(0.5, 0.999),
        **_GAMMA,
    },
}
_INT_PARAMS = frozenset({"horizon", "max_pedestrians", "max_steps"})
_REQUIRED = {"paper": ("scenario",), "drive": ("scenario",)}
_SWEEP_FORMS = ("values", "linspace", "uniform", "randint", "choice")
_RANDOM_FORMS = ("uniform", "randint", "choice")


# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RecordOptions:
    """What each episode record carries beyond the standard fields."""

    check_relaxed: bool = False  # re-check relaxed steps with the independent SLSQP (random families)
    step_times: bool = False  # every step's wall time (ms) in the record; else only a histogram

    def __post_init__(self) -> None:
        check_fields(self, Dotted("record"), SpecError)


@dataclass(frozen=True)
class SweepPoint:
    """One parameter setting of a sweep; ``point_id`` hashes (family, params, record options)."""

    sweep: str
    index: int
    family: str
    params: Mapping[str, Any]
    point_id: str


@dataclass(frozen=True)
class EpisodeTask:
    """One episode to run: a point and a seed; ``key`` identifies it across runs (resume)."""

    key: str
    sweep: str
    point: int
    point_id: str
    family: str
    params: Mapping[str, Any]
    seed: int
    record: RecordOptions


@dataclass(frozen=True)
class SweepSpec:
    """One family with its fixed, grid and random parameters and its seeds."""

    name: Annotated[str, _NAME]
    family: Annotated[str, OneOf(*FAMILIES)]
    seeds: tuple[int, ...]
    fixed: Mapping[str, Any] = field(default_factory=dict)
    grid: tuple[tuple[str, tuple[Any, ...]], ...] = ()
    random: tuple[tuple[str, str, tuple[Any, ...]], ...] = ()  # (name, form, args)
    random_points: Annotated[int, Integer(0)] = 0

    def __post_init__(self) -> None:
        check_fields(self, Dotted(f"sweeps.{self.name}"), SpecError)
        if not self.seeds:
            raise SpecError(f"sweeps.{self.name}.seeds must be at least one seed")
        if self.random and self.random_points < 1:
            raise SpecError(
                f"sweeps.{self.name}.random_points must be an integer >= 1 when parameters have random "
                f"forms ({', '.join(n for n, _, _ in self.random)})"
            )

    def points(self, campaign_seed: int, record: RecordOptions) -> list[SweepPoint]:
        """Grid product x random draws (seeded by the campaign seed and the sweep name)."""
        names = [n for n, _ in self.grid]
        combos = list(itertools.product(*[vals for _, vals in self.grid])) or [()]
        rng = np.random.default_rng([campaign_seed, zlib.crc32(self.name.encode())])
        draws: list[dict[str, Any]] = []
        for _ in range(self.random_points if self.random else 1):
            d: dict[str, Any] = {}
            for name, form, args in self.random:
                if form == "uniform":
                    d[name] = round(float(rng.uniform(args[0], args[1])), 6)
                elif form == "randint":
                    d[name] = int(rng.integers(args[0], args[1] + 1))
                else:
                    d[name] = args[int(rng.integers(len(args)))]
            draws.append(d)
        out = []
        for combo in combos:
            for d in draws:
                params = {**self.fixed, **dict(zip(names, combo, strict=True)), **d}
                where = Dotted(f"sweeps.{self.name}.params")
                params = {k: _check_param(self.family, k, v, where) for k, v in params.items()}
                ident = json.dumps({"family": self.family, "params": params, "record": record.__dict__}, sort_keys=True)
                pid = hashlib.sha1(ident.encode()).hexdigest()[:10]
                out.append(SweepPoint(self.name, len(out), self.family, params, pid))
        return out


@dataclass(frozen=True)
class CampaignSpec:
    """A validated campaign: sweeps, the seed of random parameter draws, batch size, record options."""

    name: Annotated[str, _NAME]
    sweeps: tuple[SweepSpec, ...]
    seed: Annotated[int, Integer(0)] = 0
    batch: Annotated[int | None, Maybe(Integer(1, note=" (episodes per Dask task)"), none="auto")] = None
    # batch None: auto (see runner.auto_batch)
    record: RecordOptions = field(default_factory=RecordOptions)
    source: Mapping[str, Any] = field(default_factory=dict, compare=False)  # the spec as loaded

    def __post_init__(self) -> None:
        check_fields(self, Dotted(), SpecError)
        if not self.sweeps:
            raise SpecError("sweeps must be a non-empty list of sweeps")
        names = [s.name for s in self.sweeps]
        if len(set(names)) != len(names):
            raise SpecError(f"sweeps: names must be unique, got {names}")

    def points(self) -> list[SweepPoint]:
        return [p for s in self.sweeps for p in s.points(self.seed, self.record)]

    def tasks(self) -> list[EpisodeTask]:
        """Every episode of the campaign, in spec order (sweep, point, seed)."""
        out = []
        for s in self.sweeps:
            for p in s.points(self.seed, self.record):
                for seed in s.seeds:
                    key = f"{s.name}:{p.point_id}:{seed}"
                    out.append(EpisodeTask(key, s.name, p.index, p.point_id, s.family, p.params, seed, self.record))
        return out


# ----------------------------------------------------------------------------------------------


def _check_param(family: str, name: str, value: Any, where: Dotted, form: str = "") -> Any:
    """``value`` checked by the rule of parameter ``name`` of ``family``; ``where``: the params
    table; ``form``: the sweep form the value is in (``values``, ``linspace``, ...)."""
    rules = PARAMS[family]
    if name not in rules:
        raise SpecError(check_keys({name: value}, rules, where, "parameter", f" for family {family!r}"))
    try:
        return rules[name](value)
    except Invalid as exc:
        raise SpecError(bad(where, f"{name}.{form}" if form else name, exc)) from None


_SEEDS = "an integer >= 1 (seeds 0..n-1), {start: s, count: n}, or a non-empty list of integers >= 0"


def _seeds(v: Any, where: Dotted) -> tuple[int, ...]:
    bad_seeds = SpecError(f"{where.key('seeds')} must be {_SEEDS}, got {v!r}")
    if isinstance(v, bool):
        raise bad_seeds
    if isinstance(v, int):
        if v < 1:
            raise bad_seeds
        return tuple(range(v))
    if isinstance(v, Mapping):
        if set(v) != {"start", "count"}:
            raise bad_seeds
        s, n = v["start"], v["count"]
        if any(isinstance(x, bool) or not isinstance(x, int) for x in (s, n)) or s < 0 or n < 1:
            raise bad_seeds
        return tuple(range(s, s + n))
    if isinstance(v, list) and v and all(isinstance(x, int) and not isinstance(x, bool) and x >= 0 for x in v):
        if len(set(v)) != len(v):
            raise SpecError(f"{where.key('seeds')}: seeds must be unique, got {v!r}")
        return tuple(v)
    raise bad_seeds


_SWEEP_KEYS = ("name", "family", "seeds", "params", "random_points")
_FORMS = ("a value or one sweep form {values: [..]}, {linspace: [lo, hi, n]}, {uniform: [lo, hi]}, "
          "{randint: [lo, hi]} or {choice: [..]}")  # fmt: skip


def _sweep_from_dict(d: Any, i: int, root: Dotted) -> SweepSpec:
    where = root.sub(f"sweeps[{i}]")
    if not isinstance(d, Mapping):
        raise SpecError(f"{where.table} must be a mapping with name, family, seeds, params, got {d!r}")
    unknown = check_keys(d, _SWEEP_KEYS, where)
    if unknown:
        raise SpecError(unknown)
    for key in ("name", "family", "seeds"):
        if key not in d:
            raise SpecError(f"missing key {key!r} in {where.table} (required)")
    try:
        name = _NAME(d["name"])
    except Invalid as exc:
        raise SpecError(bad(where, "name", exc)) from None
    where = root.sub(f"sweeps.{name}")
    family = d["family"]
    if family not in FAMILIES:
        raise SpecError(bad(where, "family", Invalid(OneOf(*FAMILIES).expected, family)))
    seeds = _seeds(d["seeds"], where)
    params = d.get("params") or {}
    if not isinstance(params, Mapping):
        raise SpecError(f"{where.key('params')} must be a mapping of parameter names to values or sweep forms")
    try:
        rp = Integer(0)(d.get("random_points", 0))
    except Invalid as exc:
        raise SpecError(bad(where, "random_points", exc)) from None
    at = where.sub("params")
    fixed: dict[str, Any] = {}
    grid: list[tuple[str, tuple[Any, ...]]] = []
    random: list[tuple[str, str, tuple[Any, ...]]] = []
    for pname, v in params.items():
        if not isinstance(v, Mapping):
            fixed[pname] = _check_param(family, pname, v, at)
            continue
        if len(v) != 1 or next(iter(v)) not in _SWEEP_FORMS:
            raise SpecError(f"{at.key(pname)} must be {_FORMS}, got {dict(v)!r}")
        form, args = next(iter(v.items()))
        pw = at.sub(pname)
        if form == "values" or form == "choice":
            if not isinstance(args, list) or not args:
                raise SpecError(f"{pw.key(form)} must be a non-empty list of values, got {args!r}")
            vals = tuple(_check_param(family, pname, x, at, form) for x in args)
            if form == "values":
                grid.append((pname, vals))
            else:
                random.append((pname, form, vals))
            continue
        if form == "linspace":
            ok = isinstance(args, list) and len(args) == 3 and isinstance(args[2], int) and args[2] >= 1
            ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) for x in args[:2])
            if not ok:
                raise SpecError(f"{pw.key(form)} must be [low, high, count] with count an integer >= 1, got {args!r}")
            vals = tuple(round(float(x), 9) for x in np.linspace(args[0], args[1], args[2]))
            if pname in _INT_PARAMS:
                vals = tuple(round(x) for x in vals)
            grid.append((pname, tuple(_check_param(family, pname, x, at, form) for x in vals)))
            continue
        ok = isinstance(args, list) and len(args) == 2
        ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) for x in args) and args[0] <= args[1]
        if form == "randint":
            ok = ok and all(isinstance(x, int) for x in args)
        if not ok:
            kind = "integers" if form == "randint" else "numbers"
            raise SpecError(f"{pw.key(form)} must be [low, high] {kind} with low <= high, got {args!r}")
        for x in args:
            _check_param(family, pname, x, at, form)
        random.append((pname, form, tuple(args)))
    for req in _REQUIRED.get(family, ()):
        if req not in params:
            raise SpecError(f"missing key {req!r} in {at.table} (required for family {family!r})")
    return SweepSpec(name, family, seeds, fixed, tuple(grid), tuple(random), rp)


_TOP_KEYS = ("name", "description", "seed", "batch", "record", "sweeps")


def spec_from_dict(d: Any, source: str = "") -> CampaignSpec:
    """Validate a loaded spec document (see the module docstring for the form); ``source``: the
    file it came from, named in every error."""
    root = Dotted(file=source)
    if not isinstance(d, Mapping):
        raise SpecError(f"{root.table} must be a mapping at the top level, got {type(d).__name__}")
    unknown = check_keys(d, _TOP_KEYS, root)
    if unknown:
        raise SpecError(unknown)
    if "name" not in d:
        raise SpecError(f"missing key 'name' in {root.table} (required)")
    rec = d.get("record") or {}
    if not isinstance(rec, Mapping):
        raise SpecError(f"{root.key('record')} must be a mapping with check_relaxed and/or step_times, got {rec!r}")
    sweeps = d.get("sweeps")
    if not isinstance(sweeps, list) or not sweeps:
        raise SpecError(f"{root.key('sweeps')} must be a non-empty list of sweeps (name, family, seeds, params)")
    top = {k: d[k] for k in ("name", "seed") if k in d}
    if d.get("batch", "auto") != "auto":
        top["batch"] = d["batch"]
    return CampaignSpec(
        sweeps=tuple(_sweep_from_dict(s, i, root) for i, s in enumerate(sweeps)),
        record=load(RecordOptions, rec, root.sub("record"), error=SpecError),
        source=dict(d),
        **_checked(CampaignSpec, top, root),
    )


def _checked(cls: type, values: dict[str, Any], where: Dotted) -> dict[str, Any]:
    """``values`` of fields of ``cls``, each checked by its rule (the first refusal raised)."""
    rules = rules_of(cls)
    for key, value in values.items():
        try:
            rules[key](value)
        except Invalid as exc:
            raise SpecError(bad(where, key, exc)) from None
    return values


def load_spec(path: str | Path) -> CampaignSpec:
    """Load and validate a ``.yaml``/``.yml`` or ``.toml`` campaign spec."""
    p = Path(path)
    if not p.is_file():
        raise SpecError(f"spec {p}: no such file")
    text = p.read_text()
    try:
        if p.suffix in (".yaml", ".yml"):
            import yaml

            doc = yaml.safe_load(text)
        elif p.suffix == ".toml":
            doc = tomllib.loads(text)
        else:
            raise SpecError(f"spec {p}: expected a .yaml, .yml or .toml file")
    except SpecError:
        raise
    except Exception as exc:  # parse errors of either format
        raise SpecError(f"spec {p}: cannot parse: {exc}") from None
    return spec_from_dict(doc, str(p))
