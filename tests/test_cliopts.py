"""Methods' options on the command line (clrender/cliopts.py), on two stand-in methods: a
flag two methods declare alike is shared, one they declare differently is prefixed for the
second, another method's flag is refused, a required one is asked for."""
from __future__ import annotations

import argparse
from types import SimpleNamespace

import pytest

from clrender import cliopts, methods
from clrender.contract import Option


def _plugin(train: dict, render: dict):
    return SimpleNamespace(train_options=train, bake_options={},
                           renderer=SimpleNamespace(RENDER_OPTIONS=render))


@pytest.fixture
def two_methods(monkeypatch):
    plugins = {
        "a": _plugin({"steps": Option(int, 3, "steps"), "size": Option(int, 1, "size"),
                      "src": Option(str, None, "source", required=True)},
                     {"fast": Option(bool, False, "fast mode")}),
        "b": _plugin({"steps": Option(int, 5, "steps too"), "size": Option(float, 1.0, "size"),
                      "wide": Option(bool, True, "wide")},
                     {"fast": Option(bool, False, "fast too")}),
    }
    monkeypatch.setattr(methods, "names", lambda: sorted(plugins))
    monkeypatch.setattr(methods, "get", plugins.__getitem__)
    parser = argparse.ArgumentParser(exit_on_error=False)
    cliopts.add_groups(parser, "train")
    cliopts.add_groups(parser, "render")
    return parser


def test_shared_and_prefixed_flags(two_methods):
    args = two_methods.parse_args(["--steps", "7", "--src", "x", "--size", "2"])
    assert cliopts.chosen(args, "train", "a") == {"steps": 7, "src": "x", "size": 2}
    args = two_methods.parse_args(["--steps", "7", "--b-size", "2.5", "--no-wide"])
    assert cliopts.chosen(args, "train", "b") == {"steps": 7, "size": 2.5, "wide": False}
    assert cliopts.chosen(two_methods.parse_args(["--fast"]), "render", "b") == {"fast": True}
    assert cliopts.chosen(two_methods.parse_args([]), "render", "a") == {}


def test_another_methods_flag_and_a_missing_required_one_are_errors(two_methods):
    args = two_methods.parse_args(["--steps", "7", "--src", "x", "--no-wide"])
    with pytest.raises(ValueError, match=r"--src does not apply to --method b \(--src is for a\)"):
        cliopts.chosen(args, "train", "b")
    with pytest.raises(ValueError, match=r"--no-wide does not apply to --method a"):
        cliopts.chosen(args, "train", "a")
    with pytest.raises(ValueError, match="--method a needs --src"):
        cliopts.chosen(two_methods.parse_args([]), "train", "a")
