"""Registries of interchangeable parts: every family (controllers, references, observers,
trackers, latency models, front ends, loss models, renderers) lists its parts by name, each with
a one-line summary, the pydantic settings model whose fields are its options, and its builder.

A family declares its registry in one place in its own package (``controller.registry``,
``observer.registry``, ``latency.models`` ...); scenario validation, the command line's choices
(``pmspm parts``), the error messages for unknown names and the generated table in
docs/parts.md all read it. This module lives in ``plant``, the bottom layer, so that every
package can declare its family without importing upwards.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from pydantic import BaseModel
from pydantic_core import PydanticUndefined


@dataclass(frozen=True)
class Option:
    """One option of a part: a field of its settings model.

    Attributes
    ----------
    name : the field's name, as written in a scenario file.
    type : the field's type, as text.
    default : the default value, as text (``"required"`` when the field has none).
    description : the field's description, with its provenance (seed section or our choice).
    """

    name: str
    type: str
    default: str
    description: str


@dataclass(frozen=True)
class Part:
    """One registered part.

    Attributes
    ----------
    name : the name scenarios and the command line use.
    summary : one sentence saying what the part is.
    build : the builder; its arguments are the family's (``Registry.build_signature``).
    settings : the pydantic model whose fields are the part's options (None: no options).
    prefix : where those fields sit in a scenario's part, e.g. ``"args."`` for a reference
        generator's fields.
    """

    name: str
    summary: str
    build: Callable[..., Any]
    settings: type[BaseModel] | None = None
    prefix: str = ""

    def options(self) -> list[Option]:
        """The part's options, from its settings model's fields (the ``kind`` discriminator
        left out: it is the part's name); a field whose default is itself a settings model
        (a controller's ``config``) is listed field by field, as ``config.<field>``."""
        return [] if self.settings is None else _options(self.settings, self.prefix, nest=True)


def _options(model: type[BaseModel], prefix: str, nest: bool) -> list[Option]:
    """The fields of ``model`` as options named ``prefix + field``, nested models expanded one
    level when ``nest``."""
    out = []
    for name, info in model.model_fields.items():
        if name == "kind":
            continue
        if info.default is not PydanticUndefined:
            default = info.default
        elif info.default_factory is not None:
            default = info.default_factory()  # type: ignore[call-arg]
        else:
            default = PydanticUndefined
        if nest and isinstance(default, BaseModel):
            out += _options(type(default), f"{prefix}{name}.", nest=False)
            continue
        text = "required" if default is PydanticUndefined else _text(default)
        out.append(Option(prefix + name, _type_text(info.annotation), text,
                          " ".join((info.description or "").split())))
    return out


def _type_text(annotation: Any) -> str:
    """A field's type as short text (``float``, ``Literal['a', 'b']``, ``PIDConfig`` ...)."""
    if isinstance(annotation, type):
        return annotation.__name__
    return str(annotation).replace("typing.", "")


def _text(value: Any) -> str:
    """A default value as short text: a settings model by its class name (its own options are
    listed where it is documented), anything else by ``repr``."""
    if isinstance(value, BaseModel):
        return f"{type(value).__name__}()"
    return repr(value)


@dataclass
class Registry:
    """The parts of one family, by name.

    Parameters
    ----------
    family : the family's name, singular (``"controller"``, ``"tracker"``), as ``pmspm parts``
        lists it.
    description : what the family's parts do, one sentence.
    build_signature : what every builder of the family takes and returns, e.g.
        ``"(settings, plant, clock) -> Controller"``.
    selected_by : how a scenario names a part of the family, e.g. ``"controller: {kind: NAME}"``.
    """

    family: str
    description: str
    build_signature: str
    selected_by: str
    _parts: dict[str, Part] = field(default_factory=dict)
    _renamed: dict[str, str] = field(default_factory=dict)

    def register(self, name: str, summary: str, build: Callable[..., Any],
                 settings: type[BaseModel] | None = None, prefix: str = "") -> Part:
        """Add the part ``name`` (see ``Part`` for the arguments); ``ValueError`` if the name
        is taken."""
        if name in self._parts or name in self._renamed:
            raise ValueError(f"{self.family} {name!r} is registered twice")
        part = Part(name, summary, build, settings, prefix)
        self._parts[name] = part
        return part

    def rename(self, old: str, new: str) -> None:
        """Accept the former name ``old`` for ``new``, with a deprecation warning."""
        if new not in self._parts:
            raise ValueError(f"{self.family} {new!r} is not registered")
        self._renamed[old] = new

    def renamed(self) -> dict[str, str]:
        """Former names and the current names they stand for."""
        return dict(self._renamed)

    def names(self) -> tuple[str, ...]:
        """The registered names, in registration order."""
        return tuple(self._parts)

    def __iter__(self) -> Iterator[Part]:
        return iter(self._parts.values())

    def __contains__(self, name: object) -> bool:
        return name in self._parts

    def canonical(self, name: str) -> str:
        """``name``, or the current name of a former one (with a ``FutureWarning`` naming
        it); ``ValueError`` listing the known names for an unknown one."""
        if name in self._parts:
            return name
        if name in self._renamed:
            new = self._renamed[name]
            warnings.warn(f"{self.family} {name!r} is now called {new!r}; the old name will "
                          "be removed", FutureWarning, stacklevel=3)
            return new
        raise ValueError(self.unknown(name))

    def unknown(self, name: object) -> str:
        """The message for an unknown name: the known ones and where their options are."""
        return (f"unknown {self.family} {name!r}; choose one of {', '.join(self._parts)} "
                f"(pmspm parts {self.family} lists their options)")

    def get(self, name: str) -> Part:
        """The part ``name`` (a former name is accepted with a warning, see ``canonical``)."""
        return self._parts[self.canonical(name)]

    def as_dict(self) -> dict[str, Any]:
        """The family as plain data (``pmspm parts --json``)."""
        return {
            "family": self.family,
            "description": self.description,
            "build_signature": self.build_signature,
            "selected_by": self.selected_by,
            "renamed": self.renamed(),
            "parts": [
                {"name": p.name, "summary": p.summary,
                 "settings": p.settings.__name__ if p.settings else None,
                 "options": [o.__dict__ for o in p.options()]}
                for p in self
            ],
        }
