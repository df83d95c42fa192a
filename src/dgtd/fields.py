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
