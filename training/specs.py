"""Model specs: TOML files in ``models_spec/`` loaded into frozen, validated dataclasses.

A spec is data: a ``type`` (the registered builder that turns it into an ``nn.Module``) and its
hyper-parameters.  Layout of ``models_spec/<name>.toml``::

    name = "wskpn-3"                 # must equal the file stem for files in models_spec/
    type = "wskpn"                   # registered builder (see register / build_model)
    description = "..."
    stages = ["temporal", "prediction", "reconstruction"]   # submodule names, in order

    [inputs]
    layers = ["color", "albedo", "normal", "depth"]   # runtime.frames.PIXEL_LAYERS names
    transfer = "gamma"                                # runtime.transfer name the model applies

    samples = [                      # per-sample models (ANF, NDLE): the groups of the "samples"
      { group = "diffuse_radiance", transfer = "log1p" },   # input, runtime.frames sample groups
      { group = "normal" },                                 # (or derived ones), in this order
    ]

    [[setting]]                      # run-time knobs fed as int64 scalar inputs, zero or more
    name = "kernel_size"
    default = 13
    min = 1
    max = 31
    step = 2                         # allowed: min, min + step, ... <= max

    [[state]]                        # temporal state tensors the model carries, zero or more
    name = "accum"
    channels = 3

    [[accumulate]]                   # inputs the driver accumulates over time, zero or more
    layer = "color"                  # the model's input "color" receives the accumulation
    alpha = 0.2                      # weight of the current frame
    history_spp = 1.0                # optional: weight spp / (spp + 1) where the spp is known

    [params]                         # type-specific; the builder validates them
    ...

    [paper]                          # the paper's timing row: strings and "<stage>_ms" numbers
    ...

    [train]                          # TrainSpec; every key optional
    ...

Unknown keys, wrong types and bad values raise :class:`SpecError` naming the file and the
key (``[train].lr``).  Loading imports neither torch nor the builders; :func:`build_model`
imports them.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, from PyPI (a dependency there)
    import tomli as tomllib
import types
import typing
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Iterator, Literal, Mapping

from mcdenoise.runtime import data_path
from mcdenoise.runtime.contract import (HISTORY, OUTPUT, SAMPLES_INPUT, state_input_name, state_output_name,
                                       state_weight_name)
from mcdenoise.runtime.frames import PIXEL_LAYERS
from mcdenoise.runtime.inputs import sample_group_channels
from mcdenoise.runtime.transfer import TRANSFERS

#: Folder holding the shipped specs, one ``<name>.toml`` each.
SPEC_DIR = data_path("models_spec")

_NAME_RE = re.compile(r"^[a-z0-9][a-z0-9._-]*$")
_IDENT_RE = re.compile(r"^[a-z_][a-z0-9_]*$")


class SpecError(ValueError):
    """A spec file is malformed: the message names the file and the offending key."""


class FrozenDict(Mapping):
    """Read-only mapping (spec ``params`` and ``paper``); hashable, picklable, JSON-able via dict()."""

    __slots__ = ("_d",)

    def __init__(self, *args, **kwargs):
        object.__setattr__(self, "_d", dict(*args, **kwargs))

    def __getitem__(self, key):
        return self._d[key]

    def __iter__(self) -> Iterator:
        return iter(self._d)

    def __len__(self) -> int:
        return len(self._d)

    def __hash__(self) -> int:
        return hash(json.dumps(_plain(self), sort_keys=True))

    def __repr__(self) -> str:
        return f"FrozenDict({self._d!r})"

    def __reduce__(self):
        return (FrozenDict, (self._d,))


def _plain(v: Any) -> Any:
    """JSON-able copy: mappings -> dict, tuples -> list, Paths -> str."""
    if isinstance(v, Mapping):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, Path):
        return str(v)
    return v


def _freeze(v: Any) -> Any:
    if isinstance(v, Mapping):
        return FrozenDict({k: _freeze(x) for k, x in v.items()})
    if isinstance(v, list):
        return tuple(_freeze(x) for x in v)
    return v


# ----------------------------------------------------------------------------------------------
# Generic table -> frozen dataclass validation (also used by builders for their params)
# ----------------------------------------------------------------------------------------------

def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return " | ".join(repr(a) for a in typing.get_args(tp))
    if origin is tuple:
        return f"list of {_type_name(typing.get_args(tp)[0])}"
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", str(tp))


def _convert(value: Any, tp: Any, where: str) -> Any:
    """``value`` checked against annotation ``tp`` (bool, int, float, str, Literal, tuple[T, ...],
    Optional, Mapping); raises SpecError (message prefixed with ``where``)."""
    origin = typing.get_origin(tp)
    if tp is Any:
        return _freeze(value)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _convert(value, a, where)
            except SpecError:
                pass
        raise SpecError(f"{where}: expected {_type_name(tp)}, got {value!r}")
    if origin is Literal:
        if not any(type(value) is type(a) and value == a for a in typing.get_args(tp)):
            raise SpecError(f"{where}: expected one of {_type_name(tp)}, got {value!r}")
        return value
    if origin is tuple:
        item_tp = typing.get_args(tp)[0]
        if not isinstance(value, (list, tuple)):
            raise SpecError(f"{where}: expected {_type_name(tp)}, got {type(value).__name__} {value!r}")
        return tuple(_convert(v, item_tp, f"{where}[{i}]") for i, v in enumerate(value))
    if origin in (Mapping, dict) or tp in (Mapping, dict):
        if not isinstance(value, Mapping):
            raise SpecError(f"{where}: expected a table, got {type(value).__name__}")
        return _freeze(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise SpecError(f"{where}: expected true/false, got {type(value).__name__} {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SpecError(f"{where}: expected an integer, got {type(value).__name__} {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SpecError(f"{where}: expected a number, got {type(value).__name__} {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise SpecError(f"{where}: expected a string, got {type(value).__name__} {value!r}")
        return value
    if isinstance(tp, type) and hasattr(tp, "__dataclass_fields__"):
        if not isinstance(value, Mapping):
            raise SpecError(f"{where}: expected a table, got {type(value).__name__} {value!r}")
        return parse_table(tp, value, where)
    raise TypeError(f"{where}: unsupported annotation {tp!r} in a spec dataclass")


def parse_table(cls: type, table: Mapping[str, Any], where: str):
    """Build frozen dataclass ``cls`` from a TOML table, rejecting unknown keys.

    ``where`` prefixes every message, e.g. ``"models_spec/x.toml: [params]"``; a field's
    ``__post_init__`` may raise ValueError, which is re-raised as SpecError with the prefix.
    Missing fields take their defaults; a missing field without default is an error.
    """
    if not isinstance(table, Mapping):
        raise SpecError(f"{where}: expected a table, got {type(table).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in fields(cls) if f.init}
    unknown = [k for k in table if k not in known]
    if unknown:
        raise SpecError(f"{where}: unknown key {unknown[0]!r}"
                        f"{' (and ' + str(len(unknown) - 1) + ' more)' if len(unknown) > 1 else ''}; "
                        f"allowed: {sorted(known)}")
    kwargs = {}
    for name, f in known.items():
        if name in table:
            kwargs[name] = _convert(table[name], hints[name], f"{where}.{name}")
        elif f.default is MISSING and f.default_factory is MISSING:
            raise SpecError(f"{where}: missing required key {name!r}")
    try:
        return cls(**kwargs)
    except SpecError:
        raise
    except ValueError as e:
        raise SpecError(f"{where}: {e}") from None


# ----------------------------------------------------------------------------------------------
# The spec dataclasses
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SampleGroupSpec:
    """One per-sample feature group of the ``samples`` input: ``group`` a
    :data:`runtime.frames.SAMPLE_GROUPS` name or a derived one
    (:data:`runtime.frames.DERIVED_SAMPLE_GROUPS`); ``transfer`` the curve the model's graph
    applies to it (the driver feeds every group linear, sanitised and auto-exposed)."""

    group: str
    transfer: str = "linear"

    def __post_init__(self):
        sample_group_channels(self.group)        # ValueError naming the known groups
        if self.transfer not in TRANSFERS:
            raise ValueError(f"transfer of {self.group!r}: unknown {self.transfer!r}; known: {sorted(TRANSFERS)}")


@dataclass(frozen=True)
class InputsSpec:
    """``layers``: pixel layers fed to the model, in input order; ``transfer``: the curve
    (runtime.transfer name) the model applies to colour inside its graph; ``samples``: the
    per-sample feature groups of the ``samples`` input (empty: a pixel model)."""

    layers: tuple[str, ...]
    transfer: str = "linear"
    samples: tuple[SampleGroupSpec, ...] = ()

    def __post_init__(self):
        names = [l.name for l in PIXEL_LAYERS]
        for l in self.layers:
            if l not in names:
                raise ValueError(f"layers: unknown pixel layer {l!r}; known: {names}")
        if len(set(self.layers)) != len(self.layers):
            raise ValueError(f"layers: duplicate entries in {list(self.layers)}")
        if not self.layers and not self.samples:
            raise ValueError("layers: at least one pixel layer is needed, or per-sample groups (samples)")
        if self.transfer not in TRANSFERS:
            raise ValueError(f"transfer: unknown {self.transfer!r}; known: {sorted(TRANSFERS)}")
        groups = [g.group for g in self.samples]
        if len(set(groups)) != len(groups):
            raise ValueError(f"samples: duplicate groups in {groups}")

    @property
    def sample_groups(self) -> tuple[tuple[str, str], ...]:
        """(group, transfer) of each per-sample group, in input order."""
        return tuple((g.group, g.transfer) for g in self.samples)


@dataclass(frozen=True)
class SettingSpec:
    """A run-time knob (ANF's kernel size, §3.4): an int64 scalar graph input named ``name``
    that the driver feeds (``default`` unless the user picks another allowed value: ``min``,
    ``min + step``, ... up to ``max``); changing it needs no re-export and no re-load."""

    name: str
    default: int
    min: int
    max: int
    step: int = 1

    def __post_init__(self):
        if not _IDENT_RE.match(self.name):
            raise ValueError(f"name {self.name!r} must be a lower-case identifier")
        if self.step < 1 or self.min > self.max:
            raise ValueError(f"{self.name}: need step >= 1 and min <= max, got {self.min}..{self.max} step {self.step}")
        if not (self.min <= self.default <= self.max) or (self.default - self.min) % self.step:
            raise ValueError(f"{self.name}: default {self.default} is not among {self.min}..{self.max} step {self.step}")


@dataclass(frozen=True)
class StateSpec:
    """One temporal state tensor: (N, ``channels``, H, W), carried as ``next_<name>`` ->
    reprojected by the driver -> ``prev_<name>``.

    alpha > 0: the model blends this state with the current frame itself, with the weight fed
    as graph input ``<name>_weight`` (N, 1, 1, 1): alpha, or spp / (spp + history_spp) for a
    frame of known spp, the rule of an ``[[accumulate]]`` (:meth:`runtime.temporal.Protocol.alpha`).
    0 (default): no such input."""

    name: str
    channels: int
    alpha: float = 0.0
    history_spp: float = 0.0

    def __post_init__(self):
        if not _IDENT_RE.match(self.name):
            raise ValueError(f"name {self.name!r} must be a lower-case identifier")
        if self.channels < 1:
            raise ValueError(f"channels must be >= 1, got {self.channels}")
        if not 0.0 <= self.alpha <= 1.0 or not self.history_spp >= 0.0 or (self.history_spp and not self.alpha):
            raise ValueError(f"alpha must be in (0, 1] (0: no fed weight) and history_spp >= 0 with an alpha, "
                             f"got {self.alpha}, {self.history_spp}")


@dataclass(frozen=True)
class AccumulateSpec:
    """An input the driver (and the trainer) feeds as its temporal accumulation instead of the
    frame's value: ``accum_t = layer_t + (warp(accum_{t-1}) - layer_t)·history·(1 - alpha)``
    (:func:`runtime.temporal.accumulate`; WSKPN §4.1's pre-process), ``accum_0 = layer_0``.
    The model itself is then stateless for this input.

    alpha: the current frame's weight, in (0, 1].  history_spp: when > 0, the weight of a frame
    of known spp is spp / (spp + history_spp) instead (the history counts as ``history_spp``
    samples per pixel, so a frame of more samples trusts itself more; the shipped wskpn-6's
    best fixed weight on the slow long sequence was about 0.5 at 1 spp and 0.7-0.85 at 4 spp),
    and alpha remains the weight of frames whose spp is unknown."""

    layer: str
    alpha: float
    history_spp: float = 0.0

    def __post_init__(self):
        names = [l.name for l in PIXEL_LAYERS]
        if self.layer not in names:
            raise ValueError(f"layer: unknown {self.layer!r}; known: {names}")
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha: the current frame's weight must be in (0, 1], got {self.alpha}")
        if not self.history_spp >= 0.0:
            raise ValueError(f"history_spp: samples per pixel the history counts as must be >= 0 "
                             f"(0: the fixed alpha), got {self.history_spp}")


@dataclass(frozen=True)
class TrainSpec:
    """Training defaults (the train command's flags override them).  Defaults suit 2 CPU cores.

    loss: name of a training loss (training.train.LOSSES); lr: Adam learning rate;
    batch_size: windows per step; crop: square crop side in pixels; spp: input sample counts
    drawn per item; window: consecutive frames per temporal item; steps: optimiser steps;
    minutes: wall-clock budget; temporal_weight: weight of the temporal term, the loss of the
    frame differences of output against reference (ANF §4 uses 0.25 with SMAPE);
    regularizer_weight: weight of the model's own regulariser, if it has one (ANF Eq. 9: 1e-5).
    """

    loss: str = "smape"
    lr: float = 1e-3
    batch_size: int = 8
    crop: int = 64
    spp: tuple[int, ...] = (1,)
    window: int = 2
    steps: int = 2000
    minutes: float = 20.0
    temporal_weight: float = 0.0
    regularizer_weight: float = 0.0

    def __post_init__(self):
        if not self.regularizer_weight >= 0:
            raise ValueError(f"regularizer_weight: must be >= 0, got {self.regularizer_weight}")
        if not self.loss:
            raise ValueError("loss: must be a non-empty name")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")
        for k in ("batch_size", "window", "steps"):
            if getattr(self, k) < 1:
                raise ValueError(f"{k}: must be >= 1, got {getattr(self, k)}")
        if self.crop < 8:
            raise ValueError(f"crop: must be >= 8 pixels, got {self.crop}")
        if not self.spp or any(s < 1 for s in self.spp):
            raise ValueError(f"spp: must be a non-empty list of counts >= 1, got {list(self.spp)}")
        if not self.minutes > 0:
            raise ValueError(f"minutes: must be > 0, got {self.minutes}")
        if not self.temporal_weight >= 0:
            raise ValueError(f"temporal_weight: must be >= 0, got {self.temporal_weight}")


#: Keys of [paper] that are not "<stage>_ms" numbers.
PAPER_TEXT_KEYS = ("table", "method", "device", "resolution", "note")
#: "<x>_ms" keys allowed besides the spec's stages.
PAPER_TOTAL_KEYS = ("total_ms", "graph_ms")


@dataclass(frozen=True)
class ModelSpec:
    """A validated model spec (see the module docstring for the TOML layout).

    ``params`` and ``paper`` are read-only mappings; ``raw`` is the TOML text as read and
    ``path`` the file it came from (None when parsed from text).
    """

    name: str
    type: str
    inputs: InputsSpec
    stages: tuple[str, ...]
    description: str = ""
    state: tuple[StateSpec, ...] = ()
    accumulate: tuple[AccumulateSpec, ...] = ()
    setting: tuple[SettingSpec, ...] = ()
    params: Mapping = field(default_factory=FrozenDict)
    paper: Mapping = field(default_factory=FrozenDict)
    train: TrainSpec = field(default_factory=TrainSpec)
    raw: str = field(default="", repr=False)
    path: Path | None = None

    def __post_init__(self):
        if not _NAME_RE.match(self.name):
            raise ValueError(f"name: {self.name!r} must be lower-case letters, digits, '-', '_', '.'")
        if not _IDENT_RE.match(self.type):
            raise ValueError(f"type: {self.type!r} must be a lower-case identifier")
        if not self.stages:
            raise ValueError("stages: at least one stage is needed")
        for s in self.stages:
            if not _IDENT_RE.match(s):
                raise ValueError(f"stages: {s!r} must be a lower-case identifier (it names a submodule)")
        if len(set(self.stages)) != len(self.stages):
            raise ValueError(f"stages: duplicate entries in {list(self.stages)}")
        names = [s.name for s in self.state]
        if len(set(names)) != len(names):
            raise ValueError(f"state: duplicate names in {names}")
        taken = set(self.inputs.layers) | {SAMPLES_INPUT, HISTORY} | {state_input_name(s.name) for s in self.state}
        taken |= {state_weight_name(s.name) for s in self.state if s.alpha}
        for st in self.setting:
            if st.name in taken:
                raise ValueError(f"setting: name {st.name!r} is already an input name")
        if len({st.name for st in self.setting}) != len(self.setting):
            raise ValueError(f"setting: duplicate names in {[st.name for st in self.setting]}")
        acc = [a.layer for a in self.accumulate]
        if len(set(acc)) != len(acc):
            raise ValueError(f"accumulate: duplicate layers in {acc}")
        for a in acc:
            if a not in self.inputs.layers:
                raise ValueError(f"accumulate: layer {a!r} is not among the model's inputs {list(self.inputs.layers)}")
        for k, v in self.paper.items():
            if k.endswith("_ms"):
                if k not in PAPER_TOTAL_KEYS and k[:-3] not in self.stages:
                    raise ValueError(f"paper.{k}: '<x>_ms' keys must name a stage {list(self.stages)} "
                                     f"or be one of {list(PAPER_TOTAL_KEYS)}")
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ValueError(f"paper.{k}: expected milliseconds as a number, got {v!r}")
            elif k in PAPER_TEXT_KEYS:
                if not isinstance(v, str):
                    raise ValueError(f"paper.{k}: expected a string, got {v!r}")
            else:
                raise ValueError(f"paper: unknown key {k!r}; allowed: {list(PAPER_TEXT_KEYS)}, "
                                 f"{list(PAPER_TOTAL_KEYS)}, '<stage>_ms'")

    # -- the model interface this spec implies (see training/models/__init__.py) --------------
    @property
    def input_names(self) -> tuple[str, ...]:
        """Graph inputs: pixel layers, then ``samples`` for a per-sample model, then
        ``prev_<state>``, then ``history`` if any state, then the settings."""
        names = list(self.inputs.layers) + ([SAMPLES_INPUT] if self.inputs.samples else [])
        names += [state_input_name(s.name) for s in self.state]
        names += [HISTORY] if self.state else []
        names += [state_weight_name(s.name) for s in self.state if s.alpha]
        return tuple(names + [st.name for st in self.setting])

    @property
    def protocol(self):
        """The temporal protocol of this model (:class:`runtime.temporal.Protocol`)."""
        from mcdenoise.runtime.temporal import Protocol

        return Protocol.from_spec({s.name: s.channels for s in self.state},
                                  [(a.layer, a.alpha, a.history_spp) for a in self.accumulate],
                                  {s.name: (s.alpha, s.history_spp) for s in self.state if s.alpha})

    @property
    def output_names(self) -> tuple[str, ...]:
        """Graph outputs: ``output``, then ``next_<state>``."""
        return (OUTPUT,) + tuple(state_output_name(s.name) for s in self.state)

    def params_as(self, cls: type):
        """``params`` validated into the builder's frozen dataclass ``cls`` (SpecError naming
        ``[params].<key>`` and the file on an unknown key, wrong type or bad value)."""
        return parse_table(cls, self.params, f"{self.path or self.name}: [params]")

    def to_dict(self) -> dict:
        """JSON-able content (without ``raw`` and ``path``); what :func:`spec_hash` hashes."""
        return {
            "name": self.name, "type": self.type, "description": self.description,
            "inputs": {"layers": list(self.inputs.layers), "transfer": self.inputs.transfer,
                       **({"samples": [{"group": g, "transfer": t} for g, t in self.inputs.sample_groups]}
                          if self.inputs.samples else {})},
            "stages": list(self.stages),
            # a state's fed weight came later: left out at 0, so older specs keep their hash
            "state": [{"name": s.name, "channels": s.channels,
                       **({"alpha": s.alpha, "history_spp": s.history_spp} if s.alpha else {})} for s in self.state],
            # history_spp came later: left out at 0, so older specs keep their hash
            "accumulate": [{"layer": a.layer, "alpha": a.alpha, **({"history_spp": a.history_spp} if a.history_spp else {})}
                           for a in self.accumulate],
            **({"setting": [{f.name: getattr(st, f.name) for f in fields(st)} for st in self.setting]}
               if self.setting else {}),
            "params": _plain(self.params), "paper": _plain(self.paper),
            # regularizer_weight came later: left out at its default, so older specs keep their hash
            "train": _plain({f.name: getattr(self.train, f.name) for f in fields(self.train)
                             if not (f.name == "regularizer_weight" and not self.train.regularizer_weight)}),
        }


_TOP_KEYS = ("name", "type", "description", "inputs", "stages", "state", "accumulate", "setting", "params",
             "paper", "train")


def parse_spec(text: str, source: str | os.PathLike = "<spec>") -> ModelSpec:
    """Parse and validate TOML ``text``; ``source`` names it in error messages."""
    where = str(source)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{where}: not valid TOML ({e})") from None
    unknown = [k for k in data if k not in _TOP_KEYS]
    if unknown:
        raise SpecError(f"{where}: unknown key {unknown[0]!r}; allowed top-level keys: {list(_TOP_KEYS)}")
    for k in ("name", "type", "inputs", "stages"):
        if k not in data:
            raise SpecError(f"{where}: missing required key {k!r}")
    state = data.get("state", [])
    if not isinstance(state, list):
        raise SpecError(f"{where}: state: expected an array of tables ([[state]]), got {type(state).__name__}")
    accumulate = data.get("accumulate", [])
    if not isinstance(accumulate, list):
        raise SpecError(f"{where}: accumulate: expected an array of tables ([[accumulate]]), "
                        f"got {type(accumulate).__name__}")
    setting = data.get("setting", [])
    if not isinstance(setting, list):
        raise SpecError(f"{where}: setting: expected an array of tables ([[setting]]), got {type(setting).__name__}")
    params = data.get("params", {})
    if not isinstance(params, Mapping):
        raise SpecError(f"{where}: params: expected a table ([params])")
    paper = data.get("paper", {})
    if not isinstance(paper, Mapping):
        raise SpecError(f"{where}: paper: expected a table ([paper])")
    kwargs = dict(
        name=_convert(data["name"], str, f"{where}: name"),
        type=_convert(data["type"], str, f"{where}: type"),
        description=_convert(data.get("description", ""), str, f"{where}: description"),
        inputs=parse_table(InputsSpec, data["inputs"], f"{where}: [inputs]"),
        stages=_convert(data["stages"], tuple[str, ...], f"{where}: stages"),
        state=tuple(parse_table(StateSpec, s, f"{where}: [[state]] #{i}") for i, s in enumerate(state)),
        accumulate=tuple(parse_table(AccumulateSpec, a, f"{where}: [[accumulate]] #{i}")
                         for i, a in enumerate(accumulate)),
        setting=tuple(parse_table(SettingSpec, st, f"{where}: [[setting]] #{i}") for i, st in enumerate(setting)),
        params=_freeze(params), paper=_freeze(paper),
        train=parse_table(TrainSpec, data.get("train", {}), f"{where}: [train]"),
        raw=text,
        path=Path(source) if isinstance(source, Path) else None,
    )
    try:
        return ModelSpec(**kwargs)
    except ValueError as e:
        raise SpecError(f"{where}: {e}") from None


def list_specs() -> list[str]:
    """Names of the specs shipped in ``models_spec/``, sorted."""
    return sorted(p.stem for p in SPEC_DIR.glob("*.toml"))


def load_spec(name_or_path: str | os.PathLike) -> ModelSpec:
    """Load a spec by name (``"wskpn-3"`` -> ``models_spec/wskpn-3.toml``) or by file path.

    Raises FileNotFoundError (listing the known names) or SpecError.
    """
    s = os.fspath(name_or_path)
    by_name = not (isinstance(name_or_path, Path) or s.endswith(".toml") or os.sep in s or "/" in s)
    path = SPEC_DIR / f"{s}.toml" if by_name else Path(s)
    if not path.is_file():
        raise FileNotFoundError(f"no model spec {s!r} ({path} not found); known specs: {list_specs()}")
    spec = parse_spec(path.read_text(), path)
    if path.parent.resolve() == SPEC_DIR.resolve() and spec.name != path.stem:
        raise SpecError(f"{path}: name {spec.name!r} must equal the file name {path.stem!r}")
    return spec


def spec_hash(spec: ModelSpec) -> str:
    """sha256 (hex) of the spec's validated content with defaults filled in; comments,
    key order and formatting of the TOML do not change it."""
    return hashlib.sha256(json.dumps(spec.to_dict(), sort_keys=True).encode()).hexdigest()


# ----------------------------------------------------------------------------------------------
# Builders
# ----------------------------------------------------------------------------------------------

_BUILDERS: dict[str, Callable[[ModelSpec], Any]] = {}


def register(type_name: str):
    """Decorator registering ``fn(spec) -> nn.Module`` as the builder of specs of ``type_name``."""
    if not _IDENT_RE.match(type_name):
        raise ValueError(f"builder type {type_name!r} must be a lower-case identifier")

    def deco(fn):
        old = _BUILDERS.get(type_name)
        if old is not None and (old.__module__, old.__qualname__) != (fn.__module__, fn.__qualname__):
            raise ValueError(f"model type {type_name!r} already registered by {old.__module__}.{old.__qualname__}")
        _BUILDERS[type_name] = fn
        return fn

    return deco


def registered_types() -> list[str]:
    """Registered builder types (imports the builders)."""
    import mcdenoise.training.models  # noqa: F401  (registers the builders)

    return sorted(_BUILDERS)


def build_model(spec: ModelSpec):
    """A freshly initialised ``nn.Module`` for ``spec`` (torch's global RNG seeds it), checked
    against the model interface: ``input_names``/``output_names`` as the spec implies, one
    child module per stage, ``state_channels`` matching ``[[state]]``."""
    import mcdenoise.training.models  # noqa: F401  (registers the builders; imports torch)

    if spec.type not in _BUILDERS:
        raise SpecError(f"{spec.path or spec.name}: type {spec.type!r} has no registered builder; "
                        f"known types: {sorted(_BUILDERS)}")
    model = _BUILDERS[spec.type](spec)
    where = f"builder {spec.type!r} for {spec.name!r}"
    if tuple(model.input_names) != spec.input_names:
        raise RuntimeError(f"{where}: input_names {model.input_names} != {spec.input_names}")
    if tuple(model.output_names) != spec.output_names:
        raise RuntimeError(f"{where}: output_names {model.output_names} != {spec.output_names}")
    children = dict(model.named_children())
    missing = [s for s in spec.stages if s not in children]
    if missing:
        raise RuntimeError(f"{where}: no submodule for stage(s) {missing}")
    extra = [c for c in children if c not in spec.stages]
    if extra:
        raise RuntimeError(f"{where}: top-level submodules {extra} are not stages {list(spec.stages)}; "
                           "their graph nodes would be charged to no stage")
    if dict(model.state_channels) != {s.name: s.channels for s in spec.state}:
        raise RuntimeError(f"{where}: state_channels {dict(model.state_channels)} != spec state")
    return model
