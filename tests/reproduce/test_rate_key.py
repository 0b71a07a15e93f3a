"""The rate key's text layout: written and read in one place (``rate_key.RateKey``)."""

import pytest

from lhf_hf.reproduce.rate_key import RateKey


@pytest.mark.parametrize(
    "text, key",
    [
        ("filter", RateKey("filter")),
        ("collect|darkroom|batched|ppo", RateKey("collect", "darkroom", ("batched", "ppo"))),
        ("train|darkroom|ad|paper|window", RateKey("train", "darkroom", ("ad", "paper", "window"))),
        (
            "evaluate|metaworld-reach|dicp|paper|no plan|window|ctx500",
            RateKey("evaluate", "metaworld-reach", ("dicp", "paper", "no plan", "window"), 500),
        ),
    ],
)
def test_parse_and_write_are_inverse(text, key):
    assert RateKey.parse(text) == key
    assert str(key) == text


def test_on_and_at_change_one_part():
    key = RateKey.parse("train|metaworld-reach-wall|dicp|paper|window|ctx500")
    assert str(key.on("metaworld-push")) == "train|metaworld-push|dicp|paper|window|ctx500"
    assert str(key.at(None)) == "train|metaworld-reach-wall|dicp|paper|window"
    assert str(key.at(200)) == "train|metaworld-reach-wall|dicp|paper|window|ctx200"
    assert key.without_env == "train dicp paper window ctx500"
    assert RateKey("filter").without_env == "filter"


def test_a_context_tag_is_read_only_at_the_end():
    # a field that merely starts with "ctx" is a field; only a final ctxN is the context
    key = RateKey.parse("train|darkroom|ctxfoo|paper")
    assert key.fields == ("ctxfoo", "paper") and key.context is None


@pytest.mark.parametrize(
    "make",
    [
        lambda: RateKey.parse("train||ad"),  # an empty part
        lambda: RateKey.parse(""),
        lambda: RateKey("train", "darkroom", ("a|b",)),  # the separator inside a part
        lambda: RateKey("filter", None, ("x",)),  # fields without an env
        lambda: RateKey("train", "darkroom", ("ctx40",)),  # a tag passed as a field
        lambda: RateKey("train", "darkroom", (), 0),
        lambda: RateKey("train", "darkroom", (), True),
    ],
)
def test_malformed_keys_are_refused(make):
    with pytest.raises(ValueError):
        make()
