"""The vehicle's parameter table: ordered names, typed values, index lookup."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from sitl.vehicle.flavour import ParamSpec

__all__ = ["ParamTable"]


class ParamTable:
    """Parameters in a fixed order (PARAM_VALUE.param_index is the position in it)."""

    def __init__(self, specs: Iterable[ParamSpec], overrides: Mapping[str, float] | None = None
                 ) -> None:
        self._specs: dict[str, ParamSpec] = {}
        self._values: dict[str, float] = {}
        for spec in specs:
            self._specs[spec.name] = spec
            self._values[spec.name] = float(spec.default)
        self._names = list(self._specs)
        for name, value in (overrides or {}).items():
            if not self.set(name, value):
                raise ValueError(f"unknown parameter {name!r}")

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    @property
    def names(self) -> list[str]:
        return list(self._names)

    def get(self, name: str) -> float:
        return self._values[name]

    def spec(self, name: str) -> ParamSpec:
        return self._specs[name]

    def index(self, name: str) -> int:
        return self._names.index(name)

    def name_at(self, index: int) -> str | None:
        return self._names[index] if 0 <= index < len(self._names) else None

    def set(self, name: str, value: float) -> bool:
        """Store ``value`` (rounded for integer params); False when the name is unknown."""
        spec = self._specs.get(name)
        if spec is None:
            return False
        self._values[name] = float(round(value)) if spec.is_int else float(value)
        return True
