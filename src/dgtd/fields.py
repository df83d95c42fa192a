"""A configuration field's command-line option, declared with the field it sets:
``loss: float | None = field(default=None, metadata=option("Each message is lost ..."))``.

`dgtd.cli.options` makes every run option from these fields (its name the field's flat name, `dgtd.config.FLAT`; its
type, default and choices the field's), so that an option, its help and its default are written once."""

from __future__ import annotations


def option(help: str, *, flags: tuple[str, ...] = (), metavar: str | None = None) -> dict:
    """The metadata of a field that has a command-line option: its ``help``; ``flags``, its spellings where they are
    not --field-name (``("--iterations", "-T")``; a switch's pair ``("--shared/--independent",)``); ``metavar``."""
    return {"option": {"help": help, "flags": flags, "metavar": metavar}}


def option_of(f) -> dict | None:
    """A dataclass field's option (`option`), or None where it has none."""
    return f.metadata.get("option")


STEP_SIZES = ("alpha0", "beta", "schedule")  # every run states them: they are the scenario's, not the method's


def declared(cls, name: str):
    """The field ``name`` of dataclass ``cls`` as first declared with its option (a subclass may change only its
    default), or None where no class of its line gives it one."""
    for klass in cls.__mro__:
        f = getattr(klass, "__dataclass_fields__", {}).get(name)
        if f is not None and option_of(f) is not None:
            return f
    return None


def run_options(algorithm) -> list[str]:
    """The command-line options that make ``algorithm`` (a configured instance): --algorithm, its step sizes, and
    each other field with an option where it differs from the method's default (fields without one are left out)."""
    from dataclasses import fields

    default = type(algorithm)()
    out = ["--algorithm", algorithm.name]
    for f in fields(algorithm):
        value = getattr(algorithm, f.name)
        if declared(type(algorithm), f.name) is not None and (
            f.name in STEP_SIZES or value != getattr(default, f.name)
        ):
            out += [f"--{f.name.replace('_', '-')}", str(value)]
    return out
