"""The study's search space: Hydra's sweep grammar to Optuna distributions and back."""

import json

import pytest
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

from gripdem.study.space import describe_difference, parse_space, space_record, trial_overrides


def test_the_grammar_of_the_default_study():
    space, fixed = parse_space(
        {
            "model.lr": "tag(log, interval(5e-4, 5e-3))",
            "model.hidden": "choice(32, 64)",
            "data.history_len": "range(5, 11, 5)",
            "model.layers": "int(interval(1, 4))",
            "model.decoder_dropout": "interval(0, 0.5)",
            "model.n_heads": "4",
        }
    )
    assert space["model.lr"] == FloatDistribution(5e-4, 5e-3, log=True)
    assert space["model.hidden"] == CategoricalDistribution((32, 64))
    assert space["data.history_len"] == CategoricalDistribution((5, 10))
    assert space["model.layers"] == IntDistribution(1, 4)
    assert space["model.decoder_dropout"] == FloatDistribution(0.0, 0.5)
    assert fixed == {"model.n_heads": "4"}


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"model.lr": "tag(log, interval(0, 1))"}, "log interval needs a positive lower bound"),
        ({"model.lr": "interval(1, 0.5)"}, "lower bound first"),
        ({"model.lr": "tag(linear, interval(0.1, 1))"}, "unknown tag"),
        ({"model.hidden": "32"}, "no searched key"),
        ({"model.hidden": "range(5, 5)"}, "is empty"),
        ({"model.hidden": "choice(1, 2"}, "not Hydra's sweep grammar"),
    ],
)
def test_what_cannot_be_searched_is_named(params, message):
    with pytest.raises(ValueError, match=message) as info:
        parse_space(params)
    assert str(info.value).startswith("hydra.sweeper.params")


def test_the_record_tells_two_spaces_apart_and_says_how():
    a = space_record(
        *parse_space({"model.lr": "interval(1e-4, 1e-2)", "model.hidden": "choice(32, 64)"})
    )
    same = space_record(
        *parse_space({"model.hidden": "choice(32, 64)", "model.lr": "interval(1e-4, 1e-2)"})
    )
    b = space_record(
        *parse_space({"model.lr": "interval(1e-4, 1e-1)", "model.hidden": "choice(32, 64)"})
    )
    assert a == same and a != b
    assert json.loads(a)["searched"]["model.lr"]["name"] == "FloatDistribution"
    assert describe_difference(a, b).startswith("model.lr: stored")


def test_a_trials_values_become_overrides_that_hydra_reads_back():
    overrides = trial_overrides(
        {
            "model.lr": 0.00123456789,
            "model.hidden": 64,
            "model.name": "a,b=c",
            "x": None,
            "y": True,
        },
        {"model.n_heads": "4"},
    )
    assert overrides == [
        "model.lr=0.00123456789",
        "model.hidden=64",
        "model.name='a,b=c'",
        "x=null",
        "y=true",
        "model.n_heads=4",
    ]
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(overrides)
    assert parsed[0].value() == 0.00123456789 and parsed[2].value() == "a,b=c"
