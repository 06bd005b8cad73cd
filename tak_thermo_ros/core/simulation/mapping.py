"""A scenario mapping's section read into a dataclass's values: the one reader of "unknown key (known: ...)".

Every section of a scenario YAML (the scenario itself, a unit's axis, ``handheld:``, ``powered:``,
``everyday:``, ``fleet:``) is a mapping whose keys are a dataclass's fields. :func:`fields_from_mapping`
refuses a section that is not a mapping and a key that is not a field, naming it and the
fields; each value is read by the caller's ``read`` in the mapping's order, so the first bad
key (unknown or ill-typed) is the one named. The small readers (:func:`number`,
:func:`integer`, :func:`numbers`, :func:`whole_numbers`, :func:`string`, :func:`flag`) refuse a value of the wrong type
in one line naming its key (``handheld.lever_arm_m: expected a list of three numbers``).
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any, Callable, Collection, Iterable, Mapping

from tak_thermo_ros.errors import ScenarioError


def fields_from_mapping(raw: Any, cls: type, where: str, read: Callable[[str, Any], Any], *, not_a_mapping: str,
                        noun: str = 'key', sort_known: bool = False, exclude: Collection[str] = ()) -> dict[str, Any]:
    """The values of a mapping's keys, each a field of ``cls``, read by ``read(key, value)`` in the mapping's order.

    :param where: what names a key in a message, before it (``'handheld.'``; ``''`` at the top).
    :param not_a_mapping: the message when ``raw`` is not a mapping.
    :param noun: what an unknown key is called (``'key'``, ``'scenario key'``).
    :param sort_known: list the known keys sorted (else in the fields' order).
    :param exclude: fields a mapping may not set.
    :raises ScenarioError: ``not_a_mapping``; ``{where}{key}: unknown {noun} (known: ...)``; what ``read`` raises.
    """
    if not isinstance(raw, Mapping):
        raise ScenarioError(not_a_mapping)
    known = [f.name for f in fields(cls) if f.name not in exclude]
    values: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in known:
            msg = f'{where}{key}: unknown {noun} (known: {", ".join(sorted(known) if sort_known else known)})'
            raise ScenarioError(msg)
        values[key] = read(key, value)
    return values


def number(value: Any, key: str, *, finite: bool = False) -> float:
    """``value`` as a float: an int or a float (not a bool), finite when ``finite``.

    :raises ScenarioError: ``{key}: expected a number`` (``a finite number`` when ``finite``).
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (finite and not math.isfinite(value)):
        msg = f'{key}: expected a finite number' if finite else f'{key}: expected a number'
        raise ScenarioError(msg)
    return float(value)


def integer(value: Any, key: str, *, what: str = 'an integer') -> int:
    """``value``, an int (not a bool).

    :raises ScenarioError: ``{key}: expected {what}``.
    """
    if isinstance(value, bool) or not isinstance(value, int):
        msg = f'{key}: expected {what}'
        raise ScenarioError(msg)
    return value


def numbers(value: Any, key: str, *, what: str = 'a list of numbers', length: int | None = None) -> tuple[float, ...]:
    """``value`` as a tuple of floats: a list or tuple of ints and floats (not bools), ``length`` of them if given.

    :raises ScenarioError: ``{key}: expected {what}``.
    """
    if not isinstance(value, (list, tuple)) or (length is not None and len(value) != length) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        msg = f'{key}: expected {what}'
        raise ScenarioError(msg)
    return tuple(float(v) for v in value)


def whole_numbers(value: Any, key: str, *, what: str = 'a list of whole numbers',
                  length: int | None = None) -> tuple[int, ...]:
    """``value`` as a tuple of ints: a list or tuple of ints (not bools nor floats), ``length`` of them if given.

    :raises ScenarioError: ``{key}: expected {what}``.
    """
    if not isinstance(value, (list, tuple)) or (length is not None and len(value) != length) or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in value):
        msg = f'{key}: expected {what}'
        raise ScenarioError(msg)
    return tuple(int(v) for v in value)


def string(value: Any, key: str) -> str:
    """``value``, a string.

    :raises ScenarioError: ``{key}: expected a string``.
    """
    if not isinstance(value, str):
        msg = f'{key}: expected a string'
        raise ScenarioError(msg)
    return value


def flag(value: Any, key: str) -> bool:
    """``value``, a bool.

    :raises ScenarioError: ``{key}: expected true or false``.
    """
    if not isinstance(value, bool):
        msg = f'{key}: expected true or false'
        raise ScenarioError(msg)
    return value


def first_failed(checks: Iterable[tuple[bool, str, str]], where: str = '') -> None:
    """Raise on the first ``(ok, key, problem)`` that is not ok, naming ``where.key``: a dataclass's value checks.

    :raises ScenarioError: ``WHERE.KEY: PROBLEM`` (``KEY: PROBLEM`` at a scenario's top level).
    """
    for ok, key, problem in checks:
        if not ok:
            msg = f'{where}.{key}: {problem}' if where else f'{key}: {problem}'
            raise ScenarioError(msg)
