"""What the commands print: no number without meaning (the helpers live in :mod:`vpsim.jsonsafe`, which
the library's own JSON uses too)."""

from ..jsonsafe import dumps, json_safe, number, reason

__all__ = ["dumps", "json_safe", "number", "reason"]
