"""Settings that check themselves: a bad count is one InputError line when the config is made, and the
API refuses an unknown method before its nominal pass."""

from __future__ import annotations

import dataclasses

import pytest

import coster_sumo.api as api
from coster_sumo.core.spec import GenerationConfig, LabelOptions
from coster_sumo.errors import InputError


@pytest.mark.parametrize(("field", "value", "line"), [("variants", 0, "--variants must be >= 1, not 0"),
                                                      ("samples", -3, "--samples must be >= 1, not -3")])
def test_a_bad_count_is_refused_when_the_config_is_made(field, value, line):
    with pytest.raises(InputError, match=line):
        GenerationConfig(**{field: value})
    with pytest.raises(InputError, match=line):
        dataclasses.replace(GenerationConfig(), **{field: value})


def test_label_options_check_themselves():
    with pytest.raises(InputError, match="--avoidable must be one of any, only, not 'some'"):
        LabelOptions(1.0, "some")


@pytest.mark.parametrize(("kwargs", "flag"), [({"init": "bogus"}, "--init"), ({"rollout": "gan"}, "--rollout"),
                                              ({"variants": 0}, "--variants"), ({"avoidable": "x"}, "--avoidable"),
                                              ({"variant": 3}, "unknown setting 'variant'"),
                                              ({"generation": GenerationConfig(init="bogus")}, "--init")])
def test_the_api_refuses_a_bad_setting_before_its_nominal_pass(monkeypatch, kwargs, flag):
    def no_work(*args, **kw):
        raise AssertionError("the nominal pass ran before the settings were checked")

    monkeypatch.setattr(api, "nominal_scene", no_work)
    with pytest.raises(InputError, match=flag):
        api.plan_adversaries("any.sumocfg", **kwargs)
