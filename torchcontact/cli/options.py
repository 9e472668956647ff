"""Command-line options generated from the fields of a settings dataclass.

A setting is defined once, as a typed, validated and documented field of the object it
configures (:class:`~torchcontact.environments.presets.MPCSettings`,
:class:`~torchcontact.objects.ObjectOptions`, the environment options of
:mod:`torchcontact.environments.options`). Its option is that field: ``--`` + the prefix and
the name with dashes, its type and help from the field, its validation the dataclass's own.
A field's ``metadata`` may hold ``help`` (required), ``metavar``, ``choices`` and ``parse`` (how
the option's text becomes the field's value, where its type alone does not say). An option left
out keeps the value of the object it overrides (a preset, the environment's), so every
generated option defaults to None, or for a bool field to its flag not given.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing


def option_name(name: str, prefix: str = "") -> str:
    """The option of field ``name``: ``--object-size`` for ``size`` under prefix ``object``."""
    return "--" + "-".join(filter(None, [prefix, name])).replace("_", "-")


def _destination(name: str, prefix: str) -> str:
    return "_".join(filter(None, [prefix, name]))


def add_options(
    parser: argparse.ArgumentParser,
    cls: type,
    prefix: str = "",
    title: str | None = None,
) -> None:
    """Add an option to ``parser`` for each field of dataclass ``cls``, in a group titled
    ``title`` (default the first line of the class's docstring)."""
    title = title or (cls.__doc__ or cls.__name__).strip().splitlines()[0]
    group = parser.add_argument_group(title)
    hints = typing.get_type_hints(cls)
    for field in dataclasses.fields(cls):
        meta = field.metadata
        flag, dest = option_name(field.name, prefix), _destination(field.name, prefix)
        if hints[field.name] is bool:
            on = not field.default  # a flag turns the default off or on
            flag = flag if on else "--no-" + flag[2:]
            group.add_argument(flag, dest=dest, action="store_const", const=on, help=meta["help"])
            continue
        group.add_argument(
            flag,
            dest=dest,
            type=meta.get("parse") or _parser(hints[field.name]),
            default=None,
            choices=meta.get("choices"),
            metavar=meta.get("metavar"),
            help=meta["help"],
        )


def given_options(args: argparse.Namespace, cls: type, prefix: str = "") -> dict:
    """``{field: value}`` of the options of ``cls`` given in ``args``."""
    given = {}
    for field in dataclasses.fields(cls):
        value = getattr(args, _destination(field.name, prefix), None)
        if value is not None:
            given[field.name] = value
    return given


def options_object(
    parser: argparse.ArgumentParser, args: argparse.Namespace, base, prefix: str = ""
):
    """``base`` (a dataclass instance) with the options given in ``args``; a value its class
    refuses ends the parse with the refusal, its field named as the option."""
    given = given_options(args, type(base), prefix)
    for name, value in given.items():  # one at a time, so that the error names its option
        try:
            dataclasses.replace(base, **{name: value})
        except ValueError as error:
            message = str(error)
            if not message.startswith(f"{name} "):
                message = f"{name}: {message}"
            parser.error(named_as_option(message, type(base), prefix))
    try:
        return dataclasses.replace(base, **given)
    except ValueError as error:  # values each fine, not together
        parser.error(named_as_option(str(error), type(base), prefix))


def named_as_option(message: str, cls: type, prefix: str = "") -> str:
    """``message`` with the field of ``cls`` it opens with named as its option:
    ``"--horizon must be ..."`` for ``"horizon must be ..."``."""
    for field in dataclasses.fields(cls):
        if message.startswith(f"{field.name} ") or message.startswith(f"{field.name}:"):
            return option_name(field.name, prefix) + message[len(field.name) :]
    return message


def _parser(kind) -> typing.Callable[[str], object]:
    """How an option's text becomes a value of type ``kind`` (``X | None`` as ``X``; a tuple
    from comma-separated items)."""
    if isinstance(kind, types.UnionType) or typing.get_origin(kind) is typing.Union:
        (kind,) = [k for k in typing.get_args(kind) if k is not type(None)]
    if typing.get_origin(kind) is not tuple:
        return kind
    items = typing.get_args(kind)
    variable = len(items) == 2 and items[1] is Ellipsis
    item = items[0]
    size = None if variable else len(items)

    def parse(text: str) -> tuple:
        parts = [part.strip() for part in text.split(",")]
        what = f"{size} comma-separated" if size else "comma-separated"
        noun = {float: "numbers", int: "integers", str: "names"}[item]
        if (size is not None and len(parts) != size) or not all(parts):
            raise argparse.ArgumentTypeError(f"must be {what} {noun}, got {text!r}")
        try:
            return tuple(item(part) for part in parts)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what} {noun}, got {text!r}") from None

    return parse
