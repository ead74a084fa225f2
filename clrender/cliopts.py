"""Methods' declared options (:class:`clrender.contract.Option`) on the command line: one
argument group per method, and back from the parsed flags to the chosen method's keyword
options, refusing the options of other methods.

Examples:
    >>> add_groups(train_parser, "train")          # every method's train_options
    >>> options = chosen(args, "train", "ndrf")    # {"teacher": "model.npz"} as given
"""
from __future__ import annotations

import argparse

from . import methods
from .contract import MethodSpec, Option

KINDS = {"train": "training", "render": "render", "bake": "bake"}
# Whose options a group holds, for its title and for refusing another method's flag.
OWNERS = {"train": "--method {}", "render": "a model of method {}", "bake": "a run of method {}"}


def _declared(spec: MethodSpec, kind: str) -> dict:
    return {"train": spec.train_options, "bake": spec.bake_options,
            "render": spec.renderer.RENDER_OPTIONS}[kind]


def _argument(name: str, opt: Option) -> dict:
    """argparse keywords of an option; an absent flag parses as None (not given)."""
    if opt.type is bool:
        # The help says what the flag does: a --no-X flag turns the option off.
        text = f"turn off: {opt.help} (on without this flag)" if opt.default is True else \
            f"{opt.help} (off without this flag)"
        return {"action": "store_const", "const": opt.default is not True, "default": None,
                "help": text}
    default = "" if opt.default is None else f" (default: {opt.default})"
    return {"type": opt.type, "choices": opt.choices, "nargs": opt.nargs, "default": None,
            "metavar": None if opt.choices else name.upper(), "help": opt.help + default}


def add_groups(parser: argparse.ArgumentParser, kind: str) -> None:
    """Add every method's ``kind`` options ("train": ``train_options``, "render": its
    renderer's ``RENDER_OPTIONS``, "bake": ``bake_options``) to ``parser``, one argument
    group per method. Methods declaring the same flag share it when its argparse form is
    the same; otherwise the later method's flag is prefixed with its name
    (``--<method>-<option>``)."""
    flags: dict[str, dict] = {}          # flag -> {method: option name}
    forms: dict[str, dict] = {}
    for name in methods.names():
        group = None
        for opt_name, opt in _declared(methods.get(name), kind).items():
            flag, form = opt.cli_flag(opt_name), _argument(opt_name, opt)
            if flag in forms and _bare(form) != _bare(forms[flag]):
                flag = f"--{name}-{opt_name.replace('_', '-')}"
            if flag not in forms:
                group = group or parser.add_argument_group(
                    f"{name} {KINDS[kind]} options", "for " + OWNERS[kind].format(name))
                group.add_argument(flag, dest=_dest(kind, flag), **form)
                forms[flag] = form
            flags.setdefault(flag, {})[name] = opt_name
    parser.set_defaults(**{f"_{kind}_flags": flags})


def _bare(form: dict) -> dict:
    return {k: v for k, v in form.items() if k != "help"}


def _dest(kind: str, flag: str) -> str:
    return f"_{kind}:{flag}"


def chosen(args: argparse.Namespace, kind: str, method: str) -> dict:
    """The ``kind`` options given on the command line for ``method``, by keyword.

    Raises:
        ValueError: a flag of another method was given, or a required one is missing.
    """
    flags = getattr(args, f"_{kind}_flags")
    given = {flag: getattr(args, _dest(kind, flag)) for flag in flags
             if getattr(args, _dest(kind, flag)) is not None}
    foreign = sorted(f for f in given if method not in flags[f])
    if foreign:
        owners = "; ".join(f"{f} is for {', '.join(flags[f])}" for f in foreign)
        what = OWNERS[kind].format(method)
        raise ValueError(f"{', '.join(foreign)} do{'es' if len(foreign) == 1 else ''} not "
                         f"apply to {what} ({owners})")
    declared = _declared(methods.get(method), kind)
    missing = [opt.cli_flag(n) for n, opt in declared.items()
               if opt.required and opt.cli_flag(n) not in given]
    if missing:
        raise ValueError(f"--method {method} needs {', '.join(missing)}")
    return {flags[f][method]: v for f, v in given.items()}


def whole_number(of: str = ""):
    """An argparse type: a whole number >= 1 (``of``: what it counts, for the message)."""
    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            n = 0
        if n < 1:
            raise argparse.ArgumentTypeError(
                f"expected a whole number{' of ' + of if of else ''} >= 1, got {text!r}")
        return n

    return parse
