"""One typed config: each section of run.yaml is one frozen object whose fields are the section's keys, each
default stated once (in code; the schema's descriptions quote it and a test holds them to it)."""

from __future__ import annotations

import json
import re
from dataclasses import MISSING, fields

import pytest

from slamobs.pipeline.config import SECTIONS, RunConfig, parse_config
from slamobs.pipeline.noise import DEFAULTS as NOISE_DEFAULTS
from slamobs.schemas import config_schema

#: YAML keys that are spellings of another key, not fields of their own
ALIASES = {("output", "mcap")}


def _properties(section: str) -> dict:
    """The keys of a section in the schema (``map`` is a string or a mapping: its mapping's keys)."""
    node = config_schema()["properties"][section]
    for alternative in node.get("oneOf", [node]):
        if "properties" in alternative:
            return alternative["properties"]
    raise AssertionError(f"no keys for {section} in the schema")


def _defaults(cls) -> dict:
    out = {}
    for f in fields(cls):
        if f.default is not MISSING:
            out[f.name] = f.default
        elif f.default_factory is not MISSING:
            out[f.name] = f.default_factory()
    return out


@pytest.mark.parametrize("section", sorted(SECTIONS))
def test_section_fields_are_the_schema_keys(section):
    keys = set(_properties(section))
    names = {f.name for f in fields(SECTIONS[section])}
    assert names == keys - {k for s, k in ALIASES if s == section}


def _quoted_default(description: str) -> float | None:
    """The number a description quotes as the default ('(default 0.5)', '(default 21.1, ...', 'default 3.54e-4:')."""
    found = re.search(r"\(default:? (-?[0-9][0-9.e+-]*)", description)
    return float(found.group(1).rstrip(".")) if found else None


def test_schema_descriptions_quote_the_code_defaults():
    checked = 0
    for section, cls in SECTIONS.items():
        defaults = NOISE_DEFAULTS if section == "noise" else _defaults(cls)
        for key, prop in _properties(section).items():
            quoted = _quoted_default(prop.get("description", ""))
            if quoted is None or (section, key) in ALIASES:
                continue
            value = defaults[key][0] if section == "noise" else defaults[key]
            assert float(value) == pytest.approx(quoted, rel=0.01), f"{section}.{key}: schema says {quoted}"
            checked += 1
    assert checked >= 20  # the descriptions quote most defaults; a parser that finds none must fail


def test_a_full_config_round_trips_through_its_dict():
    config = parse_config(
        {
            "observer": "batch",
            "topics": {"detections": "/tags"},
            "time": {"source": "auto", "max_meas_age": 1},
            "frames": {"body": "base_link", "assume_identity": ["imu"]},
            "limits": {"max_gap": None},
            "tags": {"size": 0.1, "sizes": {"3": 0.2}, "ignore": [4]},
            "evaluation": {"plots": False},
            "output": {"rate_hz": 20, "export": ["mcap", "tum"]},
            "noise": {"gyro": [1e-3, 2e-3, 3e-3]},
            "batch": {"seed": "riekf", "bias": "random-walk"},
            "gains": {"fast-adaptation": {"k_w": 2}},
        }
    )
    # a batch ships the dict to its workers (pickled) and hashes it as JSON
    assert RunConfig.from_dict(config.to_dict()) == config
    assert json.loads(json.dumps(config.to_dict(), default=list))["time"]["max_meas_age"] == 1.0
    assert config.time.max_meas_age == 1.0 and isinstance(config.time.max_meas_age, float)
    assert config.limits.max_gap is None and config.limits.min_range == 0.05
    assert config.tags.sizes == {3: 0.2} and config.output.export == ("tum", "mcap")
    assert config.noise.gyro == (1e-3, 2e-3, 3e-3) and config.batch.seed == "riekf"


@pytest.mark.parametrize(
    "data, says",
    [
        ({"topic": {"detections": "/x"}}, "('topic' was unexpected) (did you mean 'topics'?)"),
        (
            {"evaluation": {"plot": False}},
            "at evaluation: Additional properties are not allowed ('plot' was unexpected) (did you mean 'plots'?)",
        ),
        ({"unknwn_key": 3}, "(allowed: observer, topics,"),
        (
            {"observer": "hashim", "gains": {"k_p": 2}},
            "at gains.k_p: gains are given per observer, e.g. gains: {hashim: {k_p: ...}}",
        ),
        ({"gains": {"k_p": "fast"}}, "e.g. gains: {fast-adaptation: {k_p: ...}}"),
    ],
)
def test_a_config_mistake_says_what_was_meant(data, says):
    """An unknown key names the nearest allowed one (or lists them), and gains not under an observer's name say
    how gains are given ("gains.k_p: 2 is not of type 'object'" before)."""
    from slamobs.pipeline.errors import InputError

    with pytest.raises(InputError) as err:
        parse_config(data, "run.yaml")
    assert says in str(err.value)


@pytest.mark.parametrize(
    "tags, says",
    [
        (
            {"size": 800},
            "invalid config at tags.size: 800 m is no tag's edge (at most 5 m): the black square's edge in",
        ),
        ({"size": 0.8, "sizes": {3: 150}}, "at tags.sizes.3: 150 m is no tag's edge (at most 5 m): the black square's"),
    ],
)
def test_a_tag_size_in_mm_is_named_at_the_config(tags, says):
    """A tag size in mm (800 for the camera sample's 0.8 m) made every range 1000x: the run stopped at the range gate
    naming only limits.max_range (session 28). The config now names the key and the unit it looks like."""
    from slamobs.pipeline.errors import InputError

    with pytest.raises(InputError) as err:
        parse_config({"tags": tags}, "run.yaml")
    assert says in str(err.value) and "in mm?" in str(err.value), str(err.value)
    assert parse_config({"tags": {"size": 1.6}}, "run.yaml").tags.size == 1.6  # 2x off: the run's scale warning
