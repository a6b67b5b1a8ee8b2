"""The study file: what to sweep, validated once, expanded into cells.

A study is a grid: attacks (each with its parameter grid) x legs x hover
positions x seeds. One *cell* is one point of that grid; in it every listed
estimator runs on the same attacked measurement stream (offline) or flies the
same seeded flight with that estimator in the proxy (closed loop). A cell is
named by a stable hash of its definition (scenario content, leg, position,
resolved attack profile, seed, duration, mode), so a re-run of the same file
recognises what is done, and adding an estimator or a seed runs only what is new.

Parameter grids: in ``params``, a list is a grid axis and a scalar is fixed.
A parameter whose own value is a list (``links: [11, 14]``, declared with a list
default) is fixed when written as a flat list and swept when written as a list
of lists (``links: [[11, 14], [12, 15]]``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, StrictBool, field_validator, model_validator

import estimators
from attack_profiles import library
from attack_profiles.profile import Profile
from attack_profiles.resolve import resolve_profile
from estimators import noise
from evaluation.variants import SECURE_OFF, Variant, with_attribution
from secuav_common.loading import InputError, dump_json, load_model, parse_document, validate
from secuav_common.scenario import HoldTarget, Scenario, load_scenario, resolve_scenario_path

Mode = Literal["offline", "closed-loop"]
Leg = Literal["hover", "moving"]
BASELINES = ("ls", "ekf")  # undefended: the snapshot least-squares fix and the EKF, in every offline study


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class AttackSpec(_Strict):
    """A library profile name or a profile file, with parameters (lists are grid axes)."""

    profile: str = Field(description="library profile name (secuav-attack list) or a profile file")
    params: dict[str, Any] = Field(default_factory=dict, description="a list is a grid axis; a scalar is fixed")


class RecordingSpec(_Strict):
    """Recorded ranges instead of a flight (docs/recorded-ranges.md): every seed re-runs the estimators on it."""

    ranges: str = Field(description="recorded-ranges CSV (t_s, sysid, sensor_id, range_m), relative to the study")
    truth: str | None = Field(None, description="truth CSV (t_s, sysid, north_m, east_m, down_m); None: unscored")
    rate_hz: PositiveFloat | None = Field(
        None, description="output rate: the steps that are scored, and the frames with sync (default: the ranges' own)"
    )
    sync: StrictBool = Field(
        False,
        description="frame the readings at rate_hz, each frame's last reading per link taken as simultaneous "
        "(secuav-eval --sync); default false: every reading at its own time (estimators.aligned: the EKF by "
        "sequential updates, the others on a window brought to each output time) where the recording is one "
        "vehicle ranging to anchors (a wall or formation recording is framed)",
    )
    window_s: float | None = Field(
        None, gt=0, le=60,
        description="asynchronous processing: seconds of readings each output brings to its time (secuav-eval "
        "--window; default one output period, or the slowest link's reading interval when longer); links too sparse "
        "for it are refused",
    )  # fmt: skip
    name: str | None = Field(
        None, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$",
        description="what the rows' and the report's recording column call it (default: the ranges file as "
        "written); required in recordings",
    )  # fmt: skip
    scenario: str | None = Field(
        None, description="its own scenario (anchor layout), bundled name or file; default the study's scenario"
    )

    @model_validator(mode="after")
    def _window_needs_async(self) -> RecordingSpec:
        if self.sync and self.window_s is not None:
            raise ValueError(f"window_s: {self.window_s} is the asynchronous window; framed readings (sync: true) "
                             "have none, so leave one of them out")  # fmt: skip
        return self


AttackEntry = Annotated[Literal["none"] | AttackSpec, Field(description="'none' (clean runs) or a profile")]


class EstimatorSpec(_Strict):
    """An estimator with parameters of its own (a list is a grid axis for this estimator alone)."""

    name: str = Field(description="estimator name, plugin name, or package.module:Class")
    params: dict[str, Any] = Field(default_factory=dict, description="its keyword parameters; a list is a grid axis")


EstimatorEntry = Annotated[str | EstimatorSpec, Field(description="a name, or {name, params}")]


def variant_label(name: str, params: dict[str, Any]) -> str:
    if not params:
        return name
    inner = ",".join(f"{k}={json.dumps(v, sort_keys=True, separators=(',', ':'))}" for k, v in sorted(params.items()))
    return f"{name}[{inner}]"


class Study(_Strict):
    """A sweep of attacks x magnitudes x legs x positions x seeds over a set of estimators."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
    description: str = ""
    mode: Mode = "offline"
    scenario: str = Field(description="bundled scenario name or a scenario file")
    duration_s: PositiveFloat | None = Field(None, description="seconds per trial or flight (default: the scenario's)")
    legs: list[Leg] = Field(default_factory=lambda: ["hover"], min_length=1)
    positions: list[tuple[float, float]] | None = Field(
        None, description="hover points (north, east) in metres, scenario frame; default the scenario's target"
    )
    estimators: list[EstimatorEntry] = Field(
        min_length=1,
        description="names (built-in, plugin, package.module:Class), or {name, params} to tune one estimator alone "
        "(a list in its params is a grid axis for it only); closed loop also 'off'. Offline studies always run the "
        "undefended baselines ls (snapshot least squares) and ekf too, appended when not listed; a shared "
        "velocity_std_mps reaches only the estimators with a motion input",
    )
    estimator_params: dict[str, Any] = Field(
        default_factory=dict,
        description="keyword parameters every estimator of a cell gets (alpha, s, ...); a list is a grid axis",
    )
    tuning_budget: int | None = Field(
        None, ge=1, le=1000,
        description="the most parameter points any one estimator may be run at (its own grid); the suite fixes it "
        "so that every method gets the same budget",
    )  # fmt: skip
    seeds: int | list[int] = Field(description="a count (0..N-1) or an explicit list")
    attacks: list[AttackEntry] = Field(min_length=1)
    noise_scales: list[PositiveFloat] = Field(
        default_factory=lambda: [1.0], min_length=1,
        description="offline flights: the range sensors' noise std as a multiple of what the estimators are told "
        "(the scenario's); a grid axis, e.g. [1.0, 1.25, 1.5] for a noise mismatch",
    )  # fmt: skip
    settle_s: PositiveFloat = Field(5.0, description="closed loop: hold before the attack and the scoring start")
    dims: Literal[2, 3] = Field(
        3, description="anchor scenarios: 3 = full position with the downward laser a reading; 2 = height known"
    )
    recording: RecordingSpec | None = Field(
        None, description="offline: recorded ranges instead of flights (legs, positions, duration_s unused)"
    )
    recordings: list[RecordingSpec] | None = Field(
        None, min_length=1,
        description="offline: several recordings, each {name, ranges, truth, rate_hz, sync, window_s, scenario}; "
        "every cell runs on each, and the report gives each recording's tables and one across them (instead of "
        "recording)",
    )  # fmt: skip

    @field_validator("estimators", mode="before")
    @classmethod
    def _yaml_off(cls, names: Any) -> Any:
        # YAML 1.1 reads a bare `off` as false; in this list it can only mean the secure stage off.
        return [SECURE_OFF if n is False else n for n in names] if isinstance(names, list) else names

    @field_validator("estimators")
    @classmethod
    def _known_estimators(cls, entries: list[str | EstimatorSpec]) -> list[str | EstimatorSpec]:
        names = [e if isinstance(e, str) else e.name for e in entries]
        for name in names:
            if name != SECURE_OFF and not estimators.known(name):  # imports only that plugin
                raise ValueError(f"unknown estimator {name!r}; choose from {', '.join(estimators.names())}")
        if len(set(names)) != len(names):
            raise ValueError("an estimator is listed twice (give one entry, with a list in params to sweep)")
        return entries

    def estimator_names(self) -> list[str]:
        return [e if isinstance(e, str) else e.name for e in self.estimators]

    def variants(self) -> list[Variant]:
        """Every estimator at every point of its own grid, in the order written (``ValueError`` on a bad grid)."""
        out: list[Variant] = []
        for entry in self.estimators:
            if isinstance(entry, str):
                out += with_attribution(entry, entry, {}, self.mode)
                continue
            if "attribution" in entry.params:
                raise ValueError(f"{entry.name}: attribution is not a parameter to tune: a secure method's rows "
                                 "come both ways (its own output, and name+attribution)")  # fmt: skip
            points = _grid(entry.params, set())
            if self.tuning_budget is not None and len(points) > self.tuning_budget:
                raise ValueError(f"{entry.name}: {len(points)} parameter points exceed tuning_budget "
                                 f"{self.tuning_budget}")  # fmt: skip
            for p in points:
                out += with_attribution(entry.name, variant_label(entry.name, p), p, self.mode)
        return out

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, seeds: int | list[int]) -> int | list[int]:
        if isinstance(seeds, int) and not 1 <= seeds <= 100_000:
            raise ValueError("a seed count must lie in 1..100000")
        if isinstance(seeds, list) and (not seeds or len(set(seeds)) != len(seeds)):
            raise ValueError("an explicit seed list must be non-empty and without repeats")
        return seeds

    def recording_specs(self) -> list[RecordingSpec]:
        """The recordings the study runs on (``recording`` or ``recordings``); empty for flights."""
        return [self.recording] if self.recording is not None else list(self.recordings or [])

    @model_validator(mode="after")
    def _recording_rules(self) -> Study:
        if self.recording is not None and self.recordings is not None:
            raise ValueError("recording, recordings: give one recording or a list of them, not both")
        field = "recording" if self.recording is not None else "recordings"
        if self.recording_specs():
            if self.mode != "offline":
                raise ValueError(f"{field}: only offline studies read recorded ranges")
            if self.legs != ["hover"] or self.positions is not None:
                raise ValueError(f"{field}: the recording fixes the path, so leave legs and positions out")
        names = [r.name for r in self.recordings or []]
        if None in names:
            raise ValueError(f"recordings[{names.index(None)}].name: each recording needs a name (the report's "
                             "recording column)")  # fmt: skip
        if len(set(names)) != len(names):
            raise ValueError(f"recordings: a name is given twice ({sorted(names)})")
        if self.noise_scales != [1.0] and (self.recording_specs() or self.mode != "offline"):
            raise ValueError("noise_scales: only offline flights can be made noisier than their scenario says")
        if len(set(self.noise_scales)) != len(self.noise_scales):
            raise ValueError("noise_scales: without repeats")
        return self

    @model_validator(mode="after")
    def _mode_rules(self) -> Study:
        if self.mode == "offline" and SECURE_OFF in self.estimator_names():
            raise ValueError(f"estimators: {SECURE_OFF!r} is for closed-loop studies only")
        if self.mode == "closed-loop":
            if self.estimator_params or self.dims != 3 or any(isinstance(e, EstimatorSpec) for e in self.estimators):
                raise ValueError("estimator_params, dims: closed-loop flights fly the demo's secure stage as it is")
            if self.legs != ["hover"]:
                raise ValueError("legs: closed-loop flights hold the demo's target, so only [hover]")
            if self.positions is not None:
                raise ValueError("positions: closed-loop flights hold the demo's target; leave positions out")
        return self

    @model_validator(mode="before")
    @classmethod
    def _baselines(cls, data: Any) -> Any:
        # Every offline table compares against the undefended baselines: the snapshot least-squares fix and the
        # EKF run in every offline study, listed or not (appended where missing, so the study file's indices
        # in error messages stay the file's own). A closed-loop study flies the
        # demo's secure stage, where a baseline would be a different vehicle, so it is left as written.
        if not isinstance(data, dict) or data.get("mode", "offline") != "offline":
            return data
        given = data.get("estimators")
        if not isinstance(given, list) or not given:
            return data
        names = [e.get("name") if isinstance(e, dict) else getattr(e, "name", e) for e in given]
        missing = [b for b in BASELINES if b not in names]
        return {**data, "estimators": [*given, *missing]} if missing else data

    def seed_list(self) -> list[int]:
        return list(range(self.seeds)) if isinstance(self.seeds, int) else list(self.seeds)


@dataclass(frozen=True, slots=True)
class Cell:
    """One grid point; everything a worker needs, with no file to read (workers share no disk)."""

    key: str  # stable hash of the definition
    study: str
    mode: Mode
    scenario: Scenario
    duration_s: float
    leg: Leg
    position: tuple[float, float] | None  # None: the scenario's own target (wall hover, formation)
    attack: str  # profile name, or "none"
    attack_ref: str | None  # what the user wrote (library name or file), for closed-loop flights
    params: dict[str, Any]  # the grid values of this cell (the swept and fixed parameters given)
    profile: Profile | None
    seed: int
    settle_s: float
    estimator_params: dict[str, Any] = dataclasses.field(default_factory=dict)  # one grid point of the study's
    dims: int = 3  # test case 1's model (evaluation.trial.run_trial)
    recording: Any = None  # evaluation.recorded.Recorded: framed recorded streams instead of a flight
    noise_scale: float = 1.0  # the flight's range noise over what the estimators are told (Study.noise_scales)
    recording_name: str | None = None  # the rows' recording column (Study.recordings); None for flights
    # A recording's readings each at its own time (RecordingSpec.sync false, one vehicle ranging to anchors),
    # with the asynchronous window (None: one output period); False: framed, as every flight is.
    asynchronous: bool = False
    window_s: float | None = None


@dataclass(frozen=True, slots=True)
class _Source:
    """Where a cell's streams come from: flights of the study's scenario, or one recording with its scenario."""

    scenario: Scenario
    recording: Any = None  # evaluation.recorded.Recorded
    recording_hash: str | None = None
    name: str | None = None  # the recording column
    keyed_name: str | None = None  # a name the study gave (part of the key: renaming makes new rows)
    field: str = "recording"  # the study field errors name
    file: str | None = None  # the ranges file as written
    asynchronous: bool = False  # Cell.asynchronous
    window_s: float | None = None


def load_study(path: str | Path) -> Study:
    return load_model(Study, path)


def parse_study(text: str, source: str) -> Study:
    return validate(Study, parse_document(text, source), source)


def _resolve_near(ref: str, base: Path) -> str:
    """A relative file name is read next to the study file first, then from the working directory."""
    near = base / ref
    return str(near) if not Path(ref).is_absolute() and near.exists() else ref


def _declared_list_params(ref: str, profile_text: dict[str, Any] | None) -> set[str]:
    declared = (profile_text or {}).get("parameters") or {}
    return {k for k, v in declared.items() if isinstance(v, dict) and isinstance(v.get("default"), list)}


def _grid(params: dict[str, Any], list_valued: set[str]) -> list[dict[str, Any]]:
    axes: list[tuple[str, list[Any]]] = []
    for name, value in params.items():
        sweep = isinstance(value, list) and (name not in list_valued or all(isinstance(v, list) for v in value))
        if sweep and not value:
            raise ValueError(f"parameter {name!r}: an empty list sweeps nothing")
        if sweep and len({json.dumps(v, sort_keys=True) for v in value}) != len(value):
            raise ValueError(f"parameter {name!r} lists a value twice")
        axes.append((name, value if sweep else [value]))
    combos = itertools.product(*(values for _, values in axes))
    return [dict(zip((n for n, _ in axes), combo, strict=True)) for combo in combos]


def _profile_document(ref: str) -> dict[str, Any] | None:
    if ref in library.names():
        doc = parse_document(library.text(ref), f"library:{ref}")
    elif Path(ref).exists():
        doc = parse_document(Path(ref).read_bytes(), ref)
    else:
        return None
    return doc if isinstance(doc, dict) else None


def _with_position(scenario: Scenario, north: float, east: float) -> Scenario:
    """The scenario with its first vehicle starting under and holding (north, east)."""
    first = scenario.vehicles[0]
    if not isinstance(first.target, HoldTarget):
        raise ValueError(f"scenario {scenario.name!r} has no hold target, so positions cannot move it")
    down = first.target.pos_ned_m[2]
    start = first.start.model_copy(update={"pos_ned_m": (north, east, first.start.pos_ned_m[2])})
    target = first.target.model_copy(update={"pos_ned_m": (north, east, down)})
    vehicle = first.model_copy(update={"start": start, "target": target})
    return scenario.model_copy(update={"vehicles": [vehicle, *scenario.vehicles[1:]]})


def cell_key(**definition: Any) -> str:
    text = json.dumps(definition, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _load_scenario(ref: str, base: Path, source: str, field: str) -> Scenario:
    try:
        return load_scenario(resolve_scenario_path(_resolve_near(ref, base)))
    except InputError as err:
        raise InputError(source, field, ref, str(err)) from None


def _check_applies(study: Study, scenario: Scenario, source: str, where: str) -> None:
    from estimators.scenario_models import model_for

    model = model_for(scenario, study.dims)
    for i, name in enumerate(study.estimator_names()):
        if not estimators.registry.get(name).applies_to(model):
            these = ", ".join(estimators.names(model))
            reason = f"does not run on scenario {scenario.name!r}{where} (these do: {these})"
            raise InputError(source, f"estimators[{i}]", name, reason)


def expand(study: Study, source: str) -> list[Cell]:
    """Every cell of the study, in a stable order; ``InputError`` names the study field at fault."""
    base = Path(source).resolve().parent
    scenario = _load_scenario(study.scenario, base, source, "scenario")
    if study.mode == "closed-loop":
        from demos.catalog import demo_for

        try:
            demo_for(scenario)
        except ValueError as exc:
            raise InputError(source, "scenario", study.scenario, str(exc)) from None
    sources = _sources(study, scenario, base, source)
    if study.mode == "offline":
        for src in sources:
            _check_applies(study, src.scenario, source, f" ({src.field}: {src.name})" if src.name else "")
    duration = study.duration_s or scenario.duration_s
    positions: list[tuple[float, float] | None] = list(study.positions) if study.positions else [None]
    variants: list[tuple[tuple[float, float] | None, Scenario]] = []
    for i, pos in enumerate(positions):
        try:
            variants.append((pos, scenario if pos is None else _with_position(scenario, *pos)))
        except ValueError as exc:
            raise InputError(source, f"positions[{i}]", list(pos or ()), str(exc)) from None
    attacks: list[tuple[str, str | None, dict[str, Any], Profile | None]] = []
    for i, entry in enumerate(study.attacks):
        if entry == "none":
            attacks.append(("none", None, {}, None))
            continue
        assert isinstance(entry, AttackSpec)
        ref = _resolve_near(entry.profile, base)
        try:
            grid = _grid(entry.params, _declared_list_params(ref, _profile_document(ref)))
        except ValueError as exc:
            raise InputError(source, f"attacks[{i}].params", entry.params, str(exc)) from None
        for values in grid:
            try:
                profile = resolve_profile(ref, values, "--attack")
            except InputError as err:
                raise InputError(source, f"attacks[{i}]", {"profile": entry.profile, **values}, str(err)) from None
            attacks.append((profile.name, ref, values, profile))
    try:
        tunings = _grid(study.estimator_params, set())
    except ValueError as exc:
        raise InputError(source, "estimator_params", study.estimator_params, str(exc)) from None
    for i, entry in enumerate(study.estimators):
        try:
            Study.variants(study.model_copy(update={"estimators": [entry]}))
        except ValueError as exc:
            raise InputError(source, f"estimators[{i}].params", getattr(entry, "params", None), str(exc)) from None
    if study.mode == "offline":
        for scen in {dump_json(src.scenario): src.scenario for src in sources}.values():  # each layout once
            _check_tunings(study, tunings, scen, source)
    for src in sources:
        if src.recording is not None:
            _check_sparse(study, tunings, src, source)
    cells: list[Cell] = []
    seen: set[str] = set()
    for src in sources:
        scenario_hash = hashlib.sha256(dump_json(src.scenario).encode()).hexdigest()[:16]
        places = variants if src.recording is None else [(None, src.scenario)]
        for (name, ref, values, profile), tuning, leg, (pos, scen), noise_scale, seed in itertools.product(
            attacks, tunings, study.legs, places, study.noise_scales, study.seed_list()
        ):
            key = cell_key(
                mode=study.mode, scenario=scenario_hash, duration_s=duration, leg=leg, position=pos,
                attack=None if profile is None else profile.content_hash(), seed=seed,
                settle_s=study.settle_s if study.mode == "closed-loop" else None,
                # dims always: the default model changed from 2-D to 3-D (the laser a reading), so a directory of
                # older rows must not pass for this model's. estimator_params only when set.
                dims=study.dims, **({"estimator_params": tuning} if tuning else {}),
                **({"recording": src.recording_hash} if src.recording_hash else {}),
                **({"recording_name": src.keyed_name} if src.keyed_name else {}),  # only when named: old keys stay
                **({"noise_scale": noise_scale} if noise_scale != 1.0 else {}),  # only when set: old keys stay
                # Asynchronous rows are other numbers than the framed rows recordings had before: keyed apart.
                **({"processing": "asynchronous", "window_s": src.window_s} if src.asynchronous else {}),
            )  # fmt: skip
            if key in seen:  # two attack entries that resolve to the same profile: one cell
                continue
            seen.add(key)
            cells.append(Cell(key, study.name, study.mode, scen, duration, leg, pos, name, ref, values, profile, seed,
                              study.settle_s, tuning, study.dims, src.recording, noise_scale, src.name,
                              src.asynchronous, src.window_s))  # fmt: skip
    return cells


def _sources(study: Study, scenario: Scenario, base: Path, source: str) -> list[_Source]:
    """Flights of the study's scenario, or each recording framed once (cells carry it: workers share no disk)
    with its scenario and content hash."""
    specs = study.recording_specs()
    if not specs:
        return [_Source(scenario)]
    from evaluation.recorded import load_recording
    from evaluation.trial import asynchronous_by_default

    out = []
    for i, spec in enumerate(specs):
        name = spec.name or spec.ranges
        field = "recording" if study.recording is not None else f"recordings[{i}] ({name})"
        scen = scenario if spec.scenario is None else _load_scenario(spec.scenario, base, source, f"{field}.scenario")
        ranges = Path(_resolve_near(spec.ranges, base))
        truth = None if spec.truth is None else Path(_resolve_near(spec.truth, base))
        try:
            rec = load_recording(scen, ranges=ranges, truth=truth, rate_hz=spec.rate_hz)
        except InputError as err:
            raise InputError(source, field, spec.ranges, str(err)) from None
        asynchronous = not spec.sync and asynchronous_by_default(scen)
        if spec.window_s is not None and not asynchronous:
            reason = f"scenario {scen.name!r} is framed (asynchronous processing needs one vehicle ranging to anchors)"
            raise InputError(source, f"{field}.window_s", spec.window_s, reason)
        digest = hashlib.sha256(ranges.read_bytes())
        if truth is not None:
            digest.update(truth.read_bytes())
        out.append(_Source(scen, rec, f"{digest.hexdigest()[:16]}@{rec.rate_hz:.6g}", name, spec.name, field,
                           spec.ranges, asynchronous, spec.window_s))  # fmt: skip
    return out


def _check_sparse(study: Study, tunings: list[dict[str, Any]], src: _Source, source: str) -> None:
    """A recording too sparse for a calibration window, the asynchronous window or the framing rate fails the
    study file with the line ``secuav-eval`` gives (evaluation.trial.check_readings), naming the recording, its
    file, the link and the numbers, not every cell."""
    from estimators.aligned import ASYNC_PARAM
    from evaluation.trial import SparseReadings, check_readings

    own = {v.label: (v.name, v.build_params()) for v in study.variants()}
    for tuning in tunings:
        try:
            check_readings(src.scenario, src.recording.streams, study.dims, tuning, own,
                           asynchronous=src.asynchronous, window_s=src.window_s)  # fmt: skip
        except SparseReadings as err:
            if err.option in ("rate_hz", ASYNC_PARAM):
                field = f"{src.field}.{'rate_hz' if err.option == 'rate_hz' else 'window_s'}"
            else:
                field = f"estimator_params.{err.option}"
                if study.recordings is not None:  # which recording was too sparse for the study-wide option
                    field = f"{src.field}, {field}"
            reason = err.reason if study.recordings is None else f"{err.reason} (file {src.file})"
            raise InputError(source, field, err.value, reason) from None


def _check_tunings(study: Study, tunings: list[dict[str, Any]], scenario: Scenario, source: str) -> None:
    """Build every estimator with every grid point once, so a bad parameter fails the study file, not each cell."""
    from estimators.scenario_models import model_for
    from evaluation.trial import shared_params

    model = model_for(scenario, study.dims)
    for tuning in tunings:
        for v in study.variants():
            try:
                # estimators.create, plus calibration_s; a shared motion input only where there is one
                noise.create(v.name, model, **{**shared_params(v.name, tuning), **v.build_params()})
            except (TypeError, ValueError) as exc:
                where = f"estimators ({v.label})" if v.params else f"estimator_params ({v.name})"
                raise InputError(source, where, {**tuning, **v.params}, str(exc)) from None
