"""Typed reads from one TOML table of the companion's configuration, and the value checks
they use. Every failure is a :class:`ConfigError` naming ``file: table.key``, the expected
value and what was found.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from companion.protocol.wire import MAX_ID_BYTES
from utility_specs.data_fields import is_number

__all__ = ["SECRET_KEYS", "ConfigError", "Table", "described", "is_mavlink_url", "is_number",
           "is_sender_id", "known_key_expected"]


class ConfigError(ValueError):
    """A configuration that cannot be used; the text names file, key and expected value."""


SECRET_KEYS = frozenset({"fleet_key"})
"""Keys whose value an error names by its type only: a key written as a list or a table
was echoed whole to stderr (a service's journal), where other users may read it."""


def known_key_expected(name: str, known: Iterable[str]) -> str:
    """What an error expects instead of an unknown key: the closest known name first (a typo
    is the usual cause, and the full list is long), then all of them."""
    names = sorted(known)
    close = difflib.get_close_matches(name, names, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"a known key{hint}, one of {names}"


def described(name: str, got: Any) -> str:
    """``got`` as an error shows it: ``repr``, or only its type for a secret key (a string
    there is the caller's description, like ``"12 bytes"``, never the key)."""
    if name.rpartition(".")[2] in SECRET_KEYS and got is not None and not isinstance(got, str):
        return f"a {type(got).__name__} (value not shown: a secret)"
    return repr(got)


class Table:
    """Typed reads from one TOML table; errors name ``source: prefix.key``."""

    def __init__(self, raw: Any, source: str, prefix: str) -> None:
        self.source = source
        self.prefix = prefix
        if not isinstance(raw, Mapping):
            self.fail("", "a table", raw)
        self.raw: Mapping[str, Any] = raw
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix and name else (self.prefix or name)

    def fail(self, name: str, expected: str, got: Any) -> None:
        raise ConfigError(f"{self.source}: {self.key(name)}: expected {expected}, "
                          f"got {described(name, got)}")

    def get(self, name: str, default: Any, expected: str, ok: Callable[[Any], bool]) -> Any:
        self.used.add(name)
        if name not in self.raw:
            return default
        value = self.raw[name]
        if not ok(value):
            self.fail(name, expected, value)
        return value

    def string(self, name: str, default: str | None, *, required: bool = False) -> Any:
        if required and name not in self.raw:
            self.fail(name, "a non-empty string", None)
        return self.get(name, default, "a non-empty string",
                        lambda v: isinstance(v, str) and bool(v))

    def number(self, name: str, default: float, *, minimum: float = 0.0,
               strict: bool = True) -> float:
        rule = f"a number {'>' if strict else '>='} {minimum:g}"
        return float(self.get(name, default, rule, lambda v: is_number(v) and (
            v > minimum if strict else v >= minimum)))

    def integer(self, name: str, default: int, *, low: int, high: int) -> int:
        return int(self.get(name, default, f"an integer in {low}..{high}",
                            lambda v: isinstance(v, int) and not isinstance(v, bool)
                            and low <= v <= high))

    def boolean(self, name: str, default: bool) -> bool:
        return bool(self.get(name, default, "true or false", lambda v: isinstance(v, bool)))

    def table(self, name: str) -> Table:
        self.used.add(name)
        return Table(self.raw.get(name, {}), self.source, self.key(name))

    def mapping(self, name: str) -> dict[str, Any]:
        return dict(self.get(name, {}, "a table", lambda v: isinstance(v, Mapping)))

    def done(self) -> None:
        unknown = sorted(set(self.raw) - self.used)
        if unknown:  # the key is what is wrong: its value is no help ("got 'x'" misled)
            raise ConfigError(f"{self.source}: {self.key(unknown[0])}: expected "
                              f"{known_key_expected(unknown[0], self.used)}")


def is_sender_id(value: Any) -> bool:
    """What the wire protocol can carry (and ``run`` would otherwise refuse later)."""
    if not isinstance(value, str) or not value or not value.isprintable():
        return False
    return len(value.encode("utf-8", "surrogatepass")) <= MAX_ID_BYTES


_NETWORK_SCHEMES = ("udpin", "udpout", "udp", "udpbcast", "tcp", "tcpin")
_OTHER_SCHEMES = ("mcast", "ws", "wsserver", "wss")


def is_mavlink_url(value: Any) -> bool:
    """A network URL with a real port, or a serial device path (``PATH[,BAUD]``)."""
    if not isinstance(value, str) or not value or not value.isprintable():
        return False
    scheme, sep, rest = value.partition(":")
    if sep and scheme in _NETWORK_SCHEMES:
        host, sep, port = rest.rpartition(":")
        return bool(sep and host and port.isdigit() and 1 <= int(port) <= 65535)
    if sep and scheme in _OTHER_SCHEMES:
        return True
    if value.startswith(("/", "COM")):  # serial: /dev/serial0, /dev/ttyACM0,921600
        _path, _, baud = value.partition(",")
        return not baud or (baud.isdigit() and 0 < int(baud) <= 12_000_000)
    return False
