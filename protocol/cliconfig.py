"""Command lines from typed configs: one pydantic model per service, its command line derived from it.

Design notes: docs/architecture.md (protocol/cliconfig.py).
"""

from __future__ import annotations

import argparse
import enum
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, PydanticUserError, TypeAdapter, ValidationError, model_validator
from pydantic.fields import FieldInfo

M = TypeVar("M", bound=BaseModel)
_REQUIRED = object()


@dataclass(frozen=True)
class Cli:
    """Command-line details of a field, given as ``Annotated[type, Cli(...)]`` metadata."""

    flag: str | None = None  # default: --field-name
    short: str | None = None  # e.g. "-e"
    metavar: str | None = None
    group: str | None = None  # an argparse argument group's title
    hidden: bool = False  # not on the command line (set by the program, not the user)
    exclusive: str | None = None  # fields with the same name: at most one of them given


def _cli(info: FieldInfo) -> Cli:
    return next((m for m in info.metadata if isinstance(m, Cli)), Cli())


def default_of(model: type[BaseModel], name: str) -> Any:
    """A configuration's own default for one of its options, for another configuration that offers the same
    option (one place for each value)."""
    return model.model_fields[name].get_default(call_default_factory=True)


def flag_of(name: str, info: FieldInfo) -> str:
    return _cli(info).flag or "--" + name.replace("_", "-")


def _unwrap_optional(tp: Any) -> Any:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _is_list(tp: Any) -> bool:
    return typing.get_origin(_unwrap_optional(tp)) is list


def _choices(tp: Any) -> list[Any] | None:
    tp = _unwrap_optional(tp)
    if typing.get_origin(tp) is Literal:
        return list(typing.get_args(tp))
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return [m.value for m in tp]
    return None


def one_line(exc: ValidationError) -> str:
    """A validation error as one line: ``field: message; ...`` (no input echo, no URL)."""
    parts = []
    for e in exc.errors(include_url=False, include_input=False):
        where = ".".join(str(p) for p in e["loc"] if not isinstance(p, int))
        e["msg"] = e["msg"].removeprefix("Value error, ")
        parts.append(f"{where}: {e['msg']}" if where else e["msg"])
    return "; ".join(parts)


def _value_type(info: FieldInfo, item: bool) -> Any:
    """The annotated type of a field's value (``item``: of one element of a list field)."""
    tp = info.annotation
    meta = [m for m in info.metadata if not isinstance(m, Cli)]
    if item:
        tp = typing.get_args(_unwrap_optional(tp))[0]
        meta = []  # a list's own constraints (length) are checked on the whole model
    return Annotated[(tp, *meta)] if meta else tp


def arg_type(tp: Any, name: str = "value") -> Callable[[str], Any]:
    """An argparse ``type`` validating text as the (annotated) type ``tp``: a bad value is argparse's
    one-line error naming the constraint. For a command line not (yet) built from a model."""
    try:
        adapter = TypeAdapter(tp, config=ConfigDict(allow_inf_nan=False))
    except PydanticUserError:  # a model or dataclass: its own config rules
        adapter = TypeAdapter(tp)

    def parse(text: str) -> Any:
        try:
            return adapter.validate_python(text)
        except ValidationError as exc:
            raise argparse.ArgumentTypeError(one_line(exc)) from None

    parse.__name__ = name  # argparse names the type in its "invalid <type> value" message
    return parse


def exclusive_groups(model: type[BaseModel]) -> dict[str, list[str]]:
    """The model's mutually exclusive options: group name -> its fields (those with :attr:`Cli.exclusive`)."""
    groups: dict[str, list[str]] = {}
    for name, info in model.model_fields.items():
        cli = _cli(info)
        if cli.exclusive and not cli.hidden:
            groups.setdefault(cli.exclusive, []).append(name)
    return groups


class CliModel(BaseModel):
    """Base of the command-line configs: unknown fields refused, no NaN or infinity in a number, at most
    one option of each :attr:`Cli.exclusive` group away from its default."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @model_validator(mode="after")
    def _exclusive(self) -> Any:
        for names in exclusive_groups(type(self)).values():
            given = [n for n in names if getattr(self, n) != type(self).model_fields[n].get_default(
                call_default_factory=True)]
            if len(given) > 1:
                flags = [flag_of(n, type(self).model_fields[n]) for n in given]
                raise ValueError(f"{flags[0]}: not allowed with {', '.join(flags[1:])}")
        return self


def _group(parser: argparse.ArgumentParser, title: str | None) -> Any:
    if title is None:
        return parser
    for g in parser._action_groups:  # one group per title, however many models add to it
        if g.title == title:
            return g
    return parser.add_argument_group(title)


def add_options(parser: argparse.ArgumentParser, model: type[BaseModel],
                defaults: dict[str, Any] | None = None) -> argparse.ArgumentParser:
    """Add an option per field of ``model`` to ``parser``.

    ``defaults`` replace the model's for this command line (e.g. a client's ``--mode``). The
    namespace holds typed values: the defaults, or what the field's type made of the text.
    """
    defaults = defaults or {}
    exclusive: dict[str, Any] = {}  # Cli.exclusive -> its argparse group (in the group of its first field)
    members = exclusive_groups(model)
    for name, info in model.model_fields.items():
        cli = _cli(info)
        if cli.hidden:
            continue
        flags = [flag_of(name, info), *([cli.short] if cli.short else [])]
        required = info.is_required() and name not in defaults
        default = defaults.get(name, None if required else info.get_default(call_default_factory=True))
        kw: dict[str, Any] = {"dest": name, "help": info.description or ""}
        tp = _unwrap_optional(info.annotation)
        if tp is bool:
            if default:
                raise TypeError(f"{model.__name__}.{name}: a switch defaults to off (store_true)")
            kw.update(action="store_true", default=bool(default))
        else:
            is_list = _is_list(info.annotation)
            kw.update(type=arg_type(_value_type(info, is_list), name), default=default)
            if cli.metavar:
                kw["metavar"] = cli.metavar
            choices = _choices(typing.get_args(tp)[0] if is_list else tp)
            if choices is not None:
                kw["choices"] = choices
                if all(isinstance(c, str) for c in choices):
                    kw["type"] = str  # argparse checks the choice (and lists them in its error)
            if is_list:  # appended to a copy of an empty default; a non-empty one is the model's when none given
                kw.update(action="append", default=[] if not default else None)
            if required:
                kw["required"] = True
            elif default not in (None, [], ()):
                shown = ", ".join(_text(info, v, True) for v in default) if is_list else _text(info, default, False)
                kw["help"] = f"{kw['help']} (default: {shown.replace('%', '%%')})".strip()
        container = _group(parser, cli.group)
        others = [flag_of(n, model.model_fields[n]) for n in members.get(cli.exclusive or "", []) if n != name]
        if others:  # the usage line brackets them together only when adjacent: the help says it always
            kw["help"] = f"{kw['help']} (not with {', '.join(others)})".strip()
        if cli.exclusive:
            if cli.exclusive not in exclusive:
                exclusive[cli.exclusive] = container.add_mutually_exclusive_group()
            container = exclusive[cli.exclusive]
        container.add_argument(*flags, **kw)
    return parser


def has_default(action: argparse.Action) -> bool:
    """Whether an option has a default worth showing: not a switch's off, nothing (None) or an empty list
    (``0`` is a default: ``False`` is not)."""
    d = action.default
    unset = d is None or d is False or d is argparse.SUPPRESS or (isinstance(d, (list, tuple)) and not d)
    return bool(action.option_strings) and not unset \
        and not isinstance(action, (argparse._HelpAction, argparse._VersionAction))


def show_defaults(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Append ``(default: ...)`` to the help of every option of ``parser`` (and of its subcommands) that has a
    default its help does not already name: a parser written by hand shows its defaults as
    :func:`add_options` does."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # an alias is the same parser
                show_defaults(sub)
        elif has_default(action) and "default" not in (action.help or ""):
            shown = ",".join(map(str, action.default)) if isinstance(action.default, (list, tuple)) \
                else str(action.default)
            action.help = f"{action.help or ''} (default: {shown.replace('%', '%%')})".strip()
    return parser


def from_namespace(model: type[M], ns: argparse.Namespace | BaseModel, parser: argparse.ArgumentParser | None = None,
                   **overrides: Any) -> M:
    """The model of a parsed namespace (or of another model carrying the same fields); a validation
    error is the parser's one-line ``error:`` (exit 2) when a parser is given, else a ValueError."""
    values = {}
    for name, info in model.model_fields.items():
        if hasattr(ns, name):
            v = getattr(ns, name)
            if v is None and _is_list(info.annotation):
                continue  # an append option not given
            values[name] = v
    values.update(overrides)
    try:
        return model.model_validate(values)
    except ValidationError as exc:
        if parser is not None:
            parser.error(one_line(exc))
        raise ValueError(one_line(exc)) from None


def parse(model: type[M], argv: list[str] | None = None, parser: argparse.ArgumentParser | None = None,
          **parser_kw: Any) -> M:
    """Parse ``argv`` into ``model``: its parser (built when not given), then the model."""
    parser = parser or add_options(argparse.ArgumentParser(**parser_kw), model)
    return from_namespace(model, parser.parse_args(argv), parser)


def _text(info: FieldInfo, value: Any, item: bool) -> str:
    return _flat(TypeAdapter(_value_type(info, item)).dump_python(value, mode="json"))


def _flat(dumped: Any) -> str:
    """A dumped value as command-line text (a sequence comma-separated)."""
    return ",".join(map(str, dumped)) if isinstance(dumped, (list, tuple)) else str(dumped)


def to_argv(config: BaseModel, defaults: dict[str, Any] | None = None) -> list[str]:
    """The command line that :func:`parse` turns back into ``config``: every option whose value is not
    the default (``defaults``: those of the command line, as given to :func:`add_options`)."""
    defaults = defaults or {}
    argv: list[str] = []
    dumped = config.model_dump(mode="json")  # each value as its field's type writes it (one serializer for all)
    for name, info in type(config).model_fields.items():
        if _cli(info).hidden:
            continue
        value = getattr(config, name)
        if name in defaults:
            default = defaults[name]
        elif info.is_required():
            default = _REQUIRED
        else:
            default = info.get_default(call_default_factory=True)
        if value == default:
            continue
        flag = flag_of(name, info)
        if _unwrap_optional(info.annotation) is bool:
            if value:
                argv.append(flag)
            continue
        if _is_list(info.annotation):
            argv += [f"{flag}={_flat(v)}" for v in dumped[name] or []]
            continue
        if value is None:
            continue
        argv.append(f"{flag}={_flat(dumped[name])}")
    return argv
