"""Student's t beyond a threshold, for a spread estimated from a few power-ups: without scipy (the node's path).

A turn-on repeatability fitted from ``N`` records is an estimate: a new power-up's offset over it
follows Student's t with ``N - 1`` degrees of freedom, not the normal, and its tails are much
heavier where the watch sets its thresholds (4-5 sigma). :func:`t_two_sided_threshold` gives the
t's threshold for a tail probability: the tail as a regularised incomplete beta (:func:`t_outside`),
inverted by bisection.

Imports the standard library only.
"""

from __future__ import annotations

import math
from functools import lru_cache
from statistics import NormalDist


def t_outside(t: float, degrees: int) -> float:
    """``P(|T| >= t)`` for Student's t with ``degrees`` >= 1: the regularised incomplete beta ``I_x(d/2, 1/2)``.

    ``x = d / (d + t^2)``; the beta's continued fraction (Lentz's method) where it converges fast,
    else its complement: in the tails the small probability itself is summed, never ``1 - p``.
    """
    a, b = 0.5 * degrees, 0.5
    x = degrees / (degrees + t * t)
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _beta_fraction(a, b, x) / a
    return 1.0 - front * _beta_fraction(b, a, 1.0 - x) / b


def _beta_fraction(a: float, b: float, x: float) -> float:
    """The incomplete beta's continued fraction at ``x`` (Numerical Recipes' ``betacf``, modified Lentz)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    fraction = d
    for m in range(1, 10_000):
        for numerator in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                          -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1.0 + numerator * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + numerator / c
            c = c if abs(c) > tiny else tiny
            step = c * d
            fraction *= step
        if abs(step - 1.0) < 1e-15:
            break
    return fraction


def two_sided_threshold(probability: float) -> float:
    """``|z|`` beyond which a standard normal lies with ``probability``."""
    return NormalDist().inv_cdf(1.0 - max(probability, 1e-300) / 2.0)


def estimated_spread_factor(probability: float, estimates: int | None) -> float:
    """A variance's factor for a spread estimated from ``estimates`` draws, at a test's tail ``probability``.

    A new draw over a spread estimated from ``N`` of them is Student's t with ``N - 1`` degrees of
    freedom: at the watch's 4-5 sigma, 16 power-ups' spread lies 1.5x short (taken as known, it said
    healthy units stale, issue 39). The variance grows by the t's threshold over the normal's,
    squared: exact where that spread dominates a test's covariance, on the safe side elsewhere.
    1 for a spread given as known (``None``) or no tail.
    """
    if estimates is None or not probability > 0.0:
        return 1.0
    return (t_two_sided_threshold(probability, max(estimates - 1, 1)) / two_sided_threshold(probability)) ** 2


@lru_cache(maxsize=4096)
def t_two_sided_threshold(probability: float, degrees: int) -> float:
    """``|t|`` beyond which Student's t with ``degrees`` lies with ``probability``."""
    probability = min(max(probability, 1e-300), 1.0)
    normal = two_sided_threshold(probability)
    low, high = normal, max(2.0 * normal, 1.0)
    while t_outside(high, degrees) > probability and high < 1e300:
        high *= 2.0
    for _ in range(200):
        middle = 0.5 * (low + high)
        if t_outside(middle, degrees) > probability:
            low = middle
        else:
            high = middle
        if high - low <= 1e-9 * high:
            break
    return 0.5 * (low + high)
