"""Spec loading and validation (training.specs), over every shipped spec."""
from __future__ import annotations

import dataclasses
import pickle
import re

import pytest

from mcdenoise.training.specs import (SPEC_DIR, FrozenDict, ModelSpec, SpecError, build_model, list_specs, load_spec,
                            parse_spec, register, spec_hash)

SPECS = list_specs()


def _insert(raw: str, table: str, line: str) -> str:
    """``raw`` with ``line`` added to TOML table ``[table]`` (created at the end if absent)."""
    header = f"[{table}]\n"
    if header in raw:
        return raw.replace(header, header + line + "\n", 1)
    return raw + f"\n{header}{line}\n"


def _replace_key(raw: str, key: str, value: str) -> str:
    new, n = re.subn(rf"(?m)^{re.escape(key)}\s*=.*$", f"{key} = {value}", raw, count=1)
    assert n == 1, f"key {key!r} not in spec text"
    return new


def test_list_specs_finds_the_wskpn_specs():
    assert {"wskpn-3", "wskpn-6", "wskpn-mr"} <= set(SPECS)
    assert SPECS == sorted(SPECS)


@pytest.mark.parametrize("name", SPECS)
def test_spec_loads_by_name_and_path(name):
    spec = load_spec(name)
    assert isinstance(spec, ModelSpec)
    assert spec.name == name and spec.path == SPEC_DIR / f"{name}.toml"
    assert spec.raw == (SPEC_DIR / f"{name}.toml").read_text()
    by_path = load_spec(SPEC_DIR / f"{name}.toml")
    assert spec_hash(by_path) == spec_hash(spec)
    assert spec.input_names[:len(spec.inputs.layers)] == spec.inputs.layers
    assert spec.output_names[0] == "output"
    assert len(spec.output_names) == 1 + len(spec.state)
    assert ("history" in spec.input_names) == bool(spec.state)


@pytest.mark.parametrize("name", SPECS)
def test_spec_is_frozen_and_picklable(name):
    spec = load_spec(name)
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.name = "other"
    with pytest.raises(TypeError):
        spec.params["x"] = 1
    assert isinstance(spec.params, FrozenDict)
    again = pickle.loads(pickle.dumps(spec))
    assert again == spec and spec_hash(again) == spec_hash(spec)


@pytest.mark.parametrize("name", SPECS)
def test_spec_hash_ignores_comments_and_tracks_content(name):
    spec = load_spec(name)
    same = parse_spec("# a comment\n" + spec.raw + "\n# trailing\n")
    assert spec_hash(same) == spec_hash(spec)
    changed = parse_spec(_insert(re.sub(r"^batch_size\s*=.*$", "", spec.raw, count=1, flags=re.M), "train",
                                 "batch_size = 3"))
    assert changed.train.batch_size == 3
    assert spec_hash(changed) != spec_hash(spec)
    assert re.fullmatch(r"[0-9a-f]{64}", spec_hash(spec))


@pytest.mark.parametrize("name", SPECS)
def test_unknown_top_level_key_is_named(name):
    raw = "learning_rate = 0.1\n" + load_spec(name).raw
    with pytest.raises(SpecError, match=r"x\.toml: unknown key 'learning_rate'"):
        parse_spec(raw, "x.toml")


@pytest.mark.parametrize("name", SPECS)
@pytest.mark.parametrize("table", ["train", "inputs"])
def test_unknown_key_in_table_is_named(name, table):
    raw = _insert(load_spec(name).raw, table, "bogus_key = 1")
    with pytest.raises(SpecError, match=rf"my\.toml: \[{table}\]: unknown key 'bogus_key'"):
        parse_spec(raw, "my.toml")


@pytest.mark.parametrize("name", SPECS)
def test_unknown_params_key_is_named_by_the_builder(name):
    raw = _insert(load_spec(name).raw, "params", "bogus_param = 3")
    spec = parse_spec(raw, "p.toml")  # params are type-specific: the builder checks them
    with pytest.raises(SpecError, match=r"\[params\]: unknown key 'bogus_param'"):
        build_model(spec)


@pytest.mark.parametrize("name", SPECS)
@pytest.mark.parametrize("key,value,pattern", [
    ("lr", '"fast"', r"\[train\]\.lr: expected a number, got str"),
    ("batch_size", "true", r"\[train\]\.batch_size: expected an integer, got bool"),
    ("crop", "64.5", r"\[train\]\.crop: expected an integer, got float"),
    ("spp", "4", r"\[train\]\.spp: expected list of int"),
    ("window", "0", r"\[train\]: window: must be >= 1"),
])
def test_wrong_train_type_or_value_is_named(name, key, value, pattern):
    raw = _insert(load_spec(name).raw, "train", "")
    raw = _replace_key(raw, key, value) if re.search(rf"(?m)^{key}\s*=", raw) else _insert(raw, "train", f"{key} = {value}")
    with pytest.raises(SpecError, match=pattern):
        parse_spec(raw, "t.toml")


@pytest.mark.parametrize("name", SPECS)
def test_wrong_params_type_is_named(name):
    spec = load_spec(name)
    key = next(k for k, v in spec.params.items()  # an integer key named once in the file
               if type(v) is int and len(re.findall(rf"(?m)^{k}\s*=", spec.raw)) == 1)
    raw = _replace_key(spec.raw, key, '"three"')
    with pytest.raises(SpecError, match=rf"\[params\]\.{key}: expected an integer, got str"):
        build_model(parse_spec(raw, "q.toml"))


@pytest.mark.parametrize("name", SPECS)
def test_bad_inputs_are_rejected(name):
    raw = load_spec(name).raw
    with pytest.raises(SpecError, match=r"\[inputs\]: layers: unknown pixel layer 'colour'"):
        parse_spec(re.sub(r"(?m)^layers\s*=\s*\[.*\]", 'layers = ["colour"]', raw, count=1), "i.toml")
    with pytest.raises(SpecError, match=r"transfer: unknown 'filmic'"):
        parse_spec(_replace_key(raw, "transfer", '"filmic"'), "i.toml")
    with pytest.raises(SpecError, match=r"missing required key 'stages'"):
        parse_spec(re.sub(r"(?m)^stages\s*=.*$", "", raw), "i.toml")


def test_a_model_reads_pixel_layers_or_samples():
    raw = load_spec("wskpn-3").raw
    with pytest.raises(SpecError, match=r"at least one pixel layer is needed, or per-sample groups"):
        parse_spec(re.sub(r"(?m)^layers\s*=\s*\[.*\]", "layers = []", raw, count=1), "i.toml")
    ndle = load_spec("ndle-s")
    assert ndle.inputs.layers == () and ndle.input_names == ("samples",)
    with pytest.raises(SpecError, match=r"type 'ndle' reads samples only"):
        build_model(parse_spec(ndle.raw.replace("layers = []", 'layers = ["color"]', 1), "n.toml"))
    with pytest.raises(SpecError, match=r"needs the 'radiance' group"):
        build_model(parse_spec(ndle.raw.replace('{ group = "radiance", transfer = "log1p" },', ""), "n.toml"))


def test_accumulate_is_validated():
    raw = load_spec("wskpn-3").raw
    assert [(a.layer, a.alpha) for a in parse_spec(raw, "a.toml").accumulate] == [("color", 0.2)]
    block = '[[accumulate]]\nlayer = "color"\n'
    assert block in raw
    with pytest.raises(SpecError, match=r"a.toml: \[\[accumulate\]\] #0: alpha: .* \(0, 1\], got 0.0"):
        parse_spec(_replace_key(raw, "alpha", "0.0"), "a.toml")
    with pytest.raises(SpecError, match=r"\[\[accumulate\]\] #0: layer: unknown 'colour'"):
        parse_spec(raw.replace(block, block.replace('"color"', '"colour"')), "a.toml")
    with pytest.raises(SpecError, match=r"accumulate: layer 'position' is not among the model's inputs"):
        parse_spec(raw.replace(block, block.replace('"color"', '"position"')), "a.toml")
    with pytest.raises(SpecError, match=r"accumulate: duplicate layers in \['color', 'color'\]"):
        parse_spec(raw.replace(block, block + "alpha = 0.5\n" + block), "a.toml")
    with pytest.raises(SpecError, match=r"\[\[accumulate\]\] #0: unknown key 'decay'"):
        parse_spec(raw.replace(block, block + "decay = 0.5\n"), "a.toml")
    with pytest.raises(SpecError, match=r"accumulate: expected an array of tables"):
        parse_spec('accumulate = "color"\n' + re.sub(r"\[\[accumulate\]\]\n.*\n.*\n", "", raw), "a.toml")


def test_history_spp_is_validated_and_hashed_only_when_set():
    """history_spp (the spp-aware weight) defaults to 0, the fixed alpha: specs without it keep
    their hash; set, it is part of the hash and of the protocol."""
    block = '[[accumulate]]\nlayer = "color"\n'
    raw = re.sub(r"(?m)^history_spp = .*\n", "", load_spec("wskpn-3").raw)
    spec = parse_spec(raw, "a.toml")
    assert spec.accumulate[0].history_spp == 0.0
    assert spec_hash(parse_spec(raw.replace(block, block + "history_spp = 0.0\n"), "a.toml")) == spec_hash(spec)
    rule = parse_spec(raw.replace(block, block + "history_spp = 1.0\n"), "a.toml")
    assert rule.accumulate[0].history_spp == 1.0 and spec_hash(rule) != spec_hash(spec)
    assert rule.protocol.accumulate == (("color", "color", 0.2, 1.0),)
    assert load_spec("wskpn-3").protocol.accumulate == rule.protocol.accumulate
    with pytest.raises(SpecError, match=r"\[\[accumulate\]\] #0: history_spp: .* >= 0"):
        parse_spec(raw.replace(block, block + "history_spp = -1.0\n"), "a.toml")


@pytest.mark.parametrize("name", SPECS)
def test_paper_table_is_checked(name):
    spec = load_spec(name)
    assert isinstance(spec.paper["total_ms"], float)
    assert all(k[:-3] in spec.stages or k in ("total_ms", "graph_ms") for k in spec.paper if k.endswith("_ms"))
    with pytest.raises(SpecError, match=r"paper\.denoise_ms: '<x>_ms' keys must name a stage"):
        parse_spec(_insert(spec.raw, "paper", "denoise_ms = 1.0"), "x.toml")
    with pytest.raises(SpecError, match=r"paper\.total_ms: expected milliseconds as a number"):
        parse_spec(_replace_key(spec.raw, "total_ms", '"fast"'), "x.toml")


def test_wskpn_paper_numbers_are_table_3():
    rows = {"wskpn-3": (6.58, 5.47, 1.11), "wskpn-6": (12.89, 11.75, 1.14), "wskpn-mr": (22.70, 21.85, 0.85)}
    for name, (total, pred, rec) in rows.items():
        p = load_spec(name).paper
        assert (p["total_ms"], p["prediction_ms"], p["reconstruction_ms"]) == (total, pred, rec)
        assert p["device"] == "Nvidia RTX 2080 Ti" and p["resolution"] == "1280x720"


def test_unknown_spec_name_lists_known_ones():
    with pytest.raises(FileNotFoundError, match=r"no model spec 'nope'.*wskpn-3"):
        load_spec("nope")


def test_invalid_toml_names_the_file():
    with pytest.raises(SpecError, match=r"bad\.toml: not valid TOML"):
        parse_spec("name = = 1", "bad.toml")


def test_register_refuses_a_second_builder_for_a_type():
    with pytest.raises(ValueError, match="already registered"):
        register("wskpn")(lambda spec: None)


@pytest.mark.parametrize("name", SPECS)
def test_build_model_follows_the_interface(name):
    spec = load_spec(name)
    model = build_model(spec)
    assert model.input_names == spec.input_names and model.output_names == spec.output_names
    assert [n for n, _ in model.named_children()] == list(spec.stages)
    assert model.state_channels == {s.name: s.channels for s in spec.state}
    deployed = model.deploy()
    assert deployed.input_names == model.input_names and deployed.output_names == model.output_names
    assert not deployed.training and model.training  # deploy() leaves the original alone


def test_unregistered_type_is_named():
    raw = _replace_key(load_spec(SPECS[0]).raw, "type", '"nosuchtype"')
    with pytest.raises(SpecError, match=r"type 'nosuchtype' has no registered builder; known types: \["):
        build_model(parse_spec(raw, "u.toml"))
