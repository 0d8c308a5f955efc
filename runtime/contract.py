"""The contract an mcdenoise ONNX file carries in its ``metadata_props``.

The exporter writes it (:func:`contract_metadata`), the runtime driver reads it
(:func:`parse_contract`) instead of hard-coding any method's inputs, stages or state.  Every
key starts with :data:`PREFIX`; values are strings (JSON for the structured ones).  numpy/json
only: this module must stay importable without torch or onnx.

The model interface the contract describes (every method follows it, see
``training/models/__init__.py``):

* inputs, all ``float32`` ``NCHW`` with dynamic N, H, W: first the frame's pixel layers by name
  (``color`` linear HDR radiance, ``albedo``, ``normal`` screen-aligned camera-space unit vectors
  (x right, y down, z forward; see runtime/inputs.py), ``depth``
  distance from the camera centre, as in :data:`runtime.frames.PIXEL_LAYERS`), then per temporal state entry
  ``prev_<name>`` (the previous frame's ``next_<name>`` reprojected to this frame), then
  :data:`HISTORY` (N, 1, H, W) in [0, 1], the reprojection-validity mask (only when the model
  has state).  A layer the contract lists under ``accumulate`` is fed as the driver's temporal
  accumulation of that layer (:func:`runtime.temporal.accumulate`), not the frame's value;
* a per-sample model (format 3) also takes :data:`SAMPLES_INPUT` (N, S, F, H, W), layout
  :data:`SAMPLES_LAYOUT`, S dynamic: the frame's S samples of every pixel (uniform S; the
  frame format stores S samples for every pixel), their feature groups listed in the input's
  ``groups`` (:func:`runtime.inputs.sample_inputs` builds it), and any int64 scalar settings
  (:data:`KEY_SETTINGS`, e.g. ANF's kernel size) after the other inputs;
* outputs: :data:`OUTPUT` (N, 3, H, W) linear HDR, then ``next_<name>`` per state entry;
* graph node names start with ``/<stage>/`` for one of the contract's stages, so a profiler's
  per-node times sum to per-stage times (:meth:`Contract.stage_of`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Mapping

#: Version of the metadata layout below; a reader refuses files with a newer one.  2 added
#: :data:`KEY_ACCUMULATE` (a version-1 reader would feed the raw layer: silently wrong); 3 the
#: per-sample input (:data:`SAMPLES_LAYOUT`) and :data:`KEY_SETTINGS`; 4 an accumulation's
#: optional ``history_spp`` and a state's fed weight input (a version-3 reader would blend
#: with the fixed alpha, or not feed the weight at all).
FORMAT_VERSION = 4
#: Every mcdenoise key starts with this.
PREFIX = "mcdenoise."

KEY_VERSION = PREFIX + "format_version"
KEY_SPEC_NAME = PREFIX + "spec_name"
KEY_MODEL_TYPE = PREFIX + "model_type"
KEY_SPEC_TOML = PREFIX + "spec_toml"
KEY_SPEC_HASH = PREFIX + "spec_hash"
KEY_CODE_HASH = PREFIX + "code_hash"
KEY_INPUTS = PREFIX + "inputs"
KEY_OUTPUTS = PREFIX + "outputs"
KEY_STAGES = PREFIX + "stages"
KEY_STATE = PREFIX + "state"
KEY_HISTORY = PREFIX + "history_input"
#: Optional (absent: nothing accumulated); format version 2 and later.
KEY_ACCUMULATE = PREFIX + "accumulate"
#: Optional (absent: no run-time settings); format version 3 and later.
KEY_SETTINGS = PREFIX + "settings"
KEY_PAPER = PREFIX + "paper"
KEY_EXPORT = PREFIX + "export"
#: Keys a file must have (KEY_EXPORT is informational and optional).
REQUIRED_KEYS = (KEY_VERSION, KEY_SPEC_NAME, KEY_MODEL_TYPE, KEY_SPEC_TOML, KEY_SPEC_HASH,
                 KEY_CODE_HASH, KEY_INPUTS, KEY_OUTPUTS, KEY_STAGES, KEY_STATE, KEY_HISTORY,
                 KEY_PAPER)

#: Tensor names of the model interface.
OUTPUT = "output"
HISTORY = "history"
STATE_INPUT_PREFIX = "prev_"
STATE_OUTPUT_PREFIX = "next_"
LAYOUT = "NCHW"
#: The per-sample input of a per-sample model, and its layout (N, S, F, H, W).
SAMPLES_INPUT = "samples"
SAMPLES_LAYOUT = "NSCHW"


def state_input_name(state: str) -> str:
    """Graph input that receives state ``state`` from the previous frame (``prev_<state>``)."""
    return STATE_INPUT_PREFIX + state


def state_output_name(state: str) -> str:
    """Graph output that carries state ``state`` to the next frame (``next_<state>``)."""
    return STATE_OUTPUT_PREFIX + state


def state_weight_name(state: str) -> str:
    """Graph input (N, 1, 1, 1) with the current frame's weight of a state the model blends
    itself (``<state>_weight``; format 4): the driver's :meth:`runtime.temporal.Protocol.alpha`."""
    return state + "_weight"


def node_prefix(stage: str) -> str:
    """Prefix of every graph node name belonging to ``stage``: ``/<stage>/``."""
    return f"/{stage}/"


@dataclass(frozen=True)
class Contract:
    """What a model file promises.  Lists hold plain dicts (JSON objects):

    inputs:  {"name", "layer" (pixel layer name, or None for state/history), "channels",
              "layout" ("NCHW"), "transfer" (the runtime.transfer curve the driver applies
              before feeding; "linear" = feed as-is, the graph does its own pre-processing)}
    outputs: {"name", "channels", "layout", "transfer"} ("output" first)
    stages:  {"name", "node_prefix"} in execution order
    state:   {"name", "channels", "input" (graph input name), "output" (graph output name)[,
              "weight_input", "alpha", "history_spp": a state the model blends itself, with the
              weight fed as that (N, 1, 1, 1) input, computed like an accumulation's (format 4)]}
    history: name of the history-mask input ("" when the model has no state)
    accumulate: {"layer", "input" (graph input name), "channels", "alpha"[, "history_spp"]}:
             inputs the driver feeds as their temporal accumulation with current-frame weight
             ``alpha``, or spp / (spp + history_spp) for a frame of known spp (format 4)
    settings: {"name", "input", "default", "min", "max", "step"}: int64 scalar inputs the driver
             feeds (a run-time knob such as ANF's kernel size)
    A per-sample input has layout "NSCHW", "kind": "samples" and "groups": [{"group",
    "channels", "transfer" (the curve the graph applies)}], fed linear.
    paper:   the paper's reference timing row: "table", "method", "device", "resolution"
             strings and "<stage>_ms" / "total_ms" numbers (milliseconds on the paper's GPU)
    export:  informational: opset, torch version, parity error measured at export
    """

    version: int
    spec_name: str
    model_type: str
    spec_toml: str
    spec_hash: str
    code_hash: str
    inputs: tuple
    outputs: tuple
    stages: tuple
    state: tuple
    history: str
    accumulate: tuple = ()
    settings: tuple = ()
    paper: dict = field(default_factory=dict)
    export: dict = field(default_factory=dict)

    @property
    def input_names(self) -> list[str]:
        return [i["name"] for i in self.inputs]

    @property
    def output_names(self) -> list[str]:
        return [o["name"] for o in self.outputs]

    @property
    def samples_input(self) -> dict | None:
        """The per-sample input entry (layout :data:`SAMPLES_LAYOUT`), or None for a pixel model."""
        return next((i for i in self.inputs if i["layout"] == SAMPLES_LAYOUT), None)

    @property
    def temporal(self) -> bool:
        """Whether the driver keeps anything between frames (model state or accumulations)."""
        return bool(self.state or self.accumulate)

    @property
    def stage_names(self) -> list[str]:
        return [s["name"] for s in self.stages]

    def stage_of(self, node_name: str) -> str | None:
        """Stage a graph node belongs to (by its ``/<stage>/`` prefix), or None."""
        for s in self.stages:
            if node_name.startswith(s["node_prefix"]):
                return s["name"]
        return None


def _check_list(key: str, value: Any, required: tuple[str, ...]) -> tuple:
    if not isinstance(value, list):
        raise ValueError(f"model metadata {key!r}: expected a JSON list, got {type(value).__name__}")
    for i, item in enumerate(value):
        if not isinstance(item, dict):
            raise ValueError(f"model metadata {key!r}[{i}]: expected a JSON object")
        missing = [r for r in required if r not in item]
        if missing:
            raise ValueError(f"model metadata {key!r}[{i}]: missing field(s) {missing}")
    return tuple(value)


def parse_contract(custom_metadata_map: Mapping[str, str]) -> Contract:
    """Contract from a model's metadata map (onnxruntime ``get_modelmeta().custom_metadata_map``
    or ``{p.key: p.value for p in onnx_model.metadata_props}``).

    Raises ValueError: "not an mcdenoise model" when no ``mcdenoise.*`` key is present, a newer
    format version than :data:`FORMAT_VERSION`, a missing key (named), malformed JSON (key
    named), or state/history entries that do not match the inputs/outputs.
    """
    meta = dict(custom_metadata_map or {})
    if not any(k.startswith(PREFIX) for k in meta):
        raise ValueError(f"not an mcdenoise model (no {PREFIX}* metadata; keys: {sorted(meta)[:8]})")
    try:
        version = int(meta.get(KEY_VERSION, ""))
    except ValueError:
        raise ValueError(f"model metadata {KEY_VERSION!r} is {meta.get(KEY_VERSION)!r}, "
                         "expected an integer") from None
    if version > FORMAT_VERSION:
        raise ValueError(f"model format version {version} is newer than this mcdenoise reads "
                         f"(up to {FORMAT_VERSION}); update mcdenoise")
    if version < 1:
        raise ValueError(f"model metadata {KEY_VERSION!r}: invalid version {version}")
    missing = [k for k in REQUIRED_KEYS if k not in meta]
    if missing:
        raise ValueError(f"model metadata lacks key(s) {missing}")

    def js(key: str):
        try:
            return json.loads(meta[key])
        except json.JSONDecodeError as e:
            raise ValueError(f"model metadata {key!r} is not valid JSON ({e})") from None

    inputs = _check_list(KEY_INPUTS, js(KEY_INPUTS), ("name", "layer", "channels", "layout", "transfer"))
    outputs = _check_list(KEY_OUTPUTS, js(KEY_OUTPUTS), ("name", "channels", "layout", "transfer"))
    stages = _check_list(KEY_STAGES, js(KEY_STAGES), ("name", "node_prefix"))
    state = _check_list(KEY_STATE, js(KEY_STATE), ("name", "channels", "input", "output"))
    paper = js(KEY_PAPER)
    if not isinstance(paper, dict):
        raise ValueError(f"model metadata {KEY_PAPER!r}: expected a JSON object")
    export = js(KEY_EXPORT) if KEY_EXPORT in meta else {}
    history = meta[KEY_HISTORY]
    accumulate = _check_list(KEY_ACCUMULATE, js(KEY_ACCUMULATE), ("layer", "input", "channels", "alpha")) \
        if KEY_ACCUMULATE in meta else ()

    in_names = [i["name"] for i in inputs]
    out_names = [o["name"] for o in outputs]
    for t in inputs + outputs:
        if t["layout"] == SAMPLES_LAYOUT and t in inputs and version >= 3:
            groups = t.get("groups")
            if not isinstance(groups, list) or sum(int(g.get("channels", 0)) for g in groups) != t["channels"]:
                raise ValueError(f"model input {t['name']!r}: per-sample groups {groups!r} do not add up to "
                                 f"{t['channels']} channels")
        elif t["layout"] != LAYOUT:
            raise ValueError(f"model tensor {t['name']!r} has layout {t['layout']!r}; only {LAYOUT} "
                             f"(and {SAMPLES_LAYOUT} for a per-sample input) is supported")
    if not out_names or out_names[0] != OUTPUT:
        raise ValueError(f"model metadata {KEY_OUTPUTS!r}: first output must be {OUTPUT!r}, got {out_names[:1]}")
    for s in state:
        if s["input"] not in in_names or s["output"] not in out_names:
            raise ValueError(f"model state {s['name']!r}: input {s['input']!r} / output {s['output']!r} "
                             f"not among the graph's inputs {in_names} / outputs {out_names}")
        if "weight_input" in s:   # a state the model blends itself with a fed weight (format 4)
            a, hs = s.get("alpha"), s.get("history_spp", 0)
            ok = version >= 4 and s["weight_input"] in in_names and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in (a, hs)) and 0 < a <= 1 and hs >= 0
            if not ok:
                raise ValueError(f"model state {s['name']!r}: weight input {s['weight_input']!r} needs format 4, "
                                 f"an input of that name, alpha in (0, 1] and history_spp >= 0 ({s})")
    if state and history not in in_names:
        raise ValueError(f"model has state but its history input {history!r} is not among {in_names}")
    fed = {i["name"]: i for i in inputs}
    for a in accumulate:
        i = fed.get(a["input"])
        if i is None or i["layer"] != a["layer"] or i["channels"] != a["channels"]:
            raise ValueError(f"model metadata {KEY_ACCUMULATE!r}: {a['layer']!r} -> input {a['input']!r} "
                             f"({a['channels']} channels) does not match the graph's inputs {in_names}")
        alpha = a["alpha"]
        if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0 < alpha <= 1:
            raise ValueError(f"model metadata {KEY_ACCUMULATE!r}: alpha of {a['layer']!r} must be in (0, 1], "
                             f"got {alpha!r}")
        hs = a.get("history_spp", 0)
        if isinstance(hs, bool) or not isinstance(hs, (int, float)) or not hs >= 0 or (hs and version < 4):
            raise ValueError(f"model metadata {KEY_ACCUMULATE!r}: history_spp of {a['layer']!r} must be a "
                             f"number >= 0 (format 4 and later), got {hs!r} in format {version}")
    if len({a["input"] for a in accumulate}) != len(accumulate):
        raise ValueError(f"model metadata {KEY_ACCUMULATE!r}: an input is accumulated twice")
    settings = _check_list(KEY_SETTINGS, js(KEY_SETTINGS), ("name", "input", "default", "min", "max", "step")) \
        if KEY_SETTINGS in meta else ()
    for st in settings:
        ok = all(isinstance(st[k], int) and not isinstance(st[k], bool) for k in ("default", "min", "max", "step"))
        if not ok or st["step"] < 1 or not st["min"] <= st["default"] <= st["max"]:
            raise ValueError(f"model metadata {KEY_SETTINGS!r}: setting {st['name']!r} is malformed ({st})")
    return Contract(version=version, spec_name=meta[KEY_SPEC_NAME], model_type=meta[KEY_MODEL_TYPE],
                    spec_toml=meta[KEY_SPEC_TOML], spec_hash=meta[KEY_SPEC_HASH],
                    code_hash=meta[KEY_CODE_HASH], inputs=inputs, outputs=outputs, stages=stages,
                    state=state, history=history, accumulate=accumulate, settings=settings, paper=paper,
                    export=export)


def contract_metadata(contract: Contract) -> dict[str, str]:
    """The ``metadata_props`` key/value strings of ``contract`` (inverse of :func:`parse_contract`)."""
    def dump(v) -> str:
        return json.dumps(v, sort_keys=True)

    return {
        KEY_VERSION: str(contract.version),
        KEY_SPEC_NAME: contract.spec_name,
        KEY_MODEL_TYPE: contract.model_type,
        KEY_SPEC_TOML: contract.spec_toml,
        KEY_SPEC_HASH: contract.spec_hash,
        KEY_CODE_HASH: contract.code_hash,
        KEY_INPUTS: dump(list(contract.inputs)),
        KEY_OUTPUTS: dump(list(contract.outputs)),
        KEY_STAGES: dump(list(contract.stages)),
        KEY_STATE: dump(list(contract.state)),
        KEY_HISTORY: contract.history,
        KEY_ACCUMULATE: dump(list(contract.accumulate)),
        **({KEY_SETTINGS: dump(list(contract.settings))} if contract.settings else {}),
        KEY_PAPER: dump(contract.paper),
        KEY_EXPORT: dump(contract.export),
    }
