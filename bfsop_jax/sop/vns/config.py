"""The options of the VNS teacher as one frozen, hashable, picklable value: :class:`VNSConfig`.

The defaults are the reference configuration (:data:`REFERENCE`); the datasets are labelled
with shorter runs (:meth:`VNSConfig.labelling`, :data:`DEMO_LABELLING`). The same object
travels through :func:`bfsop_jax.sop.vns.solve_vns`, the batched host callback
(:mod:`bfsop_jax.sop.callback`, spawned worker processes included), the
``VNSPlanner`` of the switching strategies (a static ``jit`` argument) and the dataset
metadata (:meth:`VNSConfig.to_dict`).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from typing import Any

__all__ = ["DEMO_LABELLING", "REFERENCE", "VNSConfig"]

_INT_FIELDS = ("max_iters", "max_no_improve", "squeeze_tries")
_BOOL_FIELDS = ("trades", "reversals", "recreate")


@dataclasses.dataclass(frozen=True)
class VNSConfig:
    """Every option of the VNS teacher; the defaults are the reference configuration.

    Attributes:
        max_iters: VNS iterations (>= 0; reference 2000).
        max_no_improve: stop after this many iterations without improvement (>= 0; 1000).
        time_limit: optional wall-clock limit in seconds (>= 0), checked between batches;
            None: no limit. A time limit makes the result depend on the machine.
        width: iterations evaluated side by side (>= 1); None: from the instance size.
        trades: let local search 2 replace a set by a cheaper, lower-reward one when that
            shortens the tour (the published code's rule; see docs/sop.md).
        reversals: add segment reversals (2-opt) of the visited order to local search 2,
            scored with the current nodes (helps on tight budgets; see docs/sop.md).
        squeeze: when the search stagnates, insert one more set even though the tour then
            overshoots the budget by at most this fraction (>= 0), shorten it with
            order-only moves and keep it if it fits (0 disables). The same slack bounds
            the insertions of ``recreate``.
        squeeze_tries: how many of the cheapest overshooting insertions are tried (>= 0).
        recreate: when the search stagnates and ``squeeze`` finds nothing, try ruin and
            recreate of one or two visited sets.

    Frozen, hashable and picklable. Invalid values raise a one-line ``ValueError`` that
    names the field. Integer and float fields are normalised to ``int`` / ``float``.
    """

    max_iters: int = 2000
    max_no_improve: int = 1000
    time_limit: float | None = None
    width: int | None = None
    trades: bool = False
    reversals: bool = True
    squeeze: float = 0.3
    squeeze_tries: int = 3
    recreate: bool = True

    def __post_init__(self) -> None:
        for name in _INT_FIELDS:
            value = getattr(self, name)
            if not _is_int(value) or value < 0:
                raise ValueError(f"VNSConfig.{name} must be an integer >= 0, got {value!r}")
            object.__setattr__(self, name, int(value))
        if self.width is not None:
            if not _is_int(self.width) or self.width < 1:
                raise ValueError(
                    f"VNSConfig.width must be None or an integer >= 1, got {self.width!r}"
                )
            object.__setattr__(self, "width", int(self.width))
        if self.time_limit is not None:
            if not _is_real(self.time_limit) or not self.time_limit >= 0:
                raise ValueError(
                    f"VNSConfig.time_limit must be None or seconds >= 0, got {self.time_limit!r}"
                )
            object.__setattr__(self, "time_limit", float(self.time_limit))
        if not _is_real(self.squeeze) or not (0 <= self.squeeze < math.inf):
            raise ValueError(
                f"VNSConfig.squeeze must be a finite fraction >= 0, got {self.squeeze!r}"
            )
        object.__setattr__(self, "squeeze", float(self.squeeze))
        for name in _BOOL_FIELDS:
            value = getattr(self, name)
            if not isinstance(value, bool):
                raise ValueError(f"VNSConfig.{name} must be a bool, got {value!r}")

    @classmethod
    def labelling(cls, max_iters: int, max_no_improve: int, **options: Any) -> VNSConfig:
        """The configuration a dataset is labelled with: the reference options with a
        shorter run (``DataConfig.vns_iters`` / ``vns_no_improve``); ``options`` override
        any other field."""
        return cls(max_iters=max_iters, max_no_improve=max_no_improve, **options)

    def replace(self, **overrides: Any) -> VNSConfig:
        """A copy with some fields changed (validated). Unknown names raise ``TypeError``."""
        unknown = sorted(set(overrides) - _NAMES)
        if unknown:
            raise TypeError(f"unknown VNS option(s) {', '.join(unknown)}")
        return dataclasses.replace(self, **overrides) if overrides else self

    @classmethod
    def resolve(
        cls, config: VNSConfig | Mapping[str, Any] | None = None, **overrides: Any
    ) -> VNSConfig:
        """One config from the new and the old calling conventions.

        ``config`` (a :class:`VNSConfig`, a mapping as written by :meth:`to_dict`, or None
        for :data:`REFERENCE`) with the loose keyword options of the old API applied on top.
        """
        if config is None:
            base = REFERENCE
        elif isinstance(config, VNSConfig):
            base = config
        elif isinstance(config, Mapping):
            base = cls.from_dict(config)
        else:
            raise TypeError(f"config must be a VNSConfig, a mapping or None, got {config!r}")
        return base.replace(**overrides)

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (inverse of :meth:`from_dict`)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> VNSConfig:
        """A config from :meth:`to_dict` output; missing fields take their defaults,
        unknown ones raise ``ValueError``."""
        unknown = sorted(set(data) - _NAMES)
        if unknown:
            raise ValueError(f"unknown VNSConfig field(s) {', '.join(unknown)}")
        return cls(**dict(data))


_NAMES = frozenset(f.name for f in dataclasses.fields(VNSConfig))


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


REFERENCE = VNSConfig()
"""The reference configuration (2,000 iterations, 1,000 without improvement)."""

DEMO_LABELLING = VNSConfig.labelling(max_iters=500, max_no_improve=250)
"""How the ``demo`` distillation preset labels its data (``vns_iters=500``,
``vns_no_improve=250``)."""
