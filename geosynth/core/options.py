"""How does an entry point take its settings: as keywords, or as one options object?

Each method declares, checks and documents its settings once, in a frozen dataclass
(``VolumeOptions``, ``PointTextureOptions``, ``TexturingOptions``, ``CompletionOptions``;
issue 33). Its entry points keep the keyword form for users and also take ``options=``;
:func:`settings_from` turns either into the one checked object and refuses both at once.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar

__all__ = ["keyword_defaults", "settings_from"]

Options = TypeVar("Options")


def keyword_defaults(function: Callable, names: Iterable[str]) -> dict[str, Any]:
    """The defaults of ``function``'s parameters ``names`` (as written in its signature)."""
    parameters = inspect.signature(function).parameters
    return {name: parameters[name].default for name in names}


def _same(value, default) -> bool:
    """Whether a keyword still holds its default (an array compares as changed)."""
    if value is default:
        return True
    try:
        return bool(value == default)
    except (TypeError, ValueError):  # an array's element-wise answer
        return False


def settings_from(options_type: type[Options], options: Options | None, keywords: Mapping[str, Any],
                  defaults: Mapping[str, Any], build: Callable[[], Options] | None = None) -> Options:
    """The settings of one call as one checked ``options_type`` object.

    Args:
        options_type: the method's frozen options dataclass.
        options: what the caller gave as ``options=`` (None: the keywords hold the settings).
        keywords: the settings as the caller's keywords, by the options' field names.
        defaults: each keyword's default in the entry point's signature
            (:func:`keyword_defaults`).
        build: makes the object from the keywords when they are nested (None:
            ``options_type(**keywords)``).

    Returns:
        ``options`` itself, or the object made from the keywords (every value checked there).

    Raises:
        TypeError: ``options`` of another type.
        ValueError: a bad keyword (the options' own message), or ``options`` given beside
            keywords that differ from their defaults.
    """
    if options is None:
        return options_type(**keywords) if build is None else build()
    if not isinstance(options, options_type):
        raise TypeError(f"options must be a {options_type.__name__}, got {type(options).__name__}.")
    changed = sorted(name for name, value in keywords.items() if not _same(value, defaults[name]))
    if changed:
        raise ValueError(f"give the settings either as options= or as keywords, not both ({', '.join(changed)} "
                         "given beside options=).")
    return options
