"""Leg pairing into persons (thesis 4.3.3): closest first, or the best matching, optionally
anchored on where the tracked target should be; and the persons as the wire message."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

from followbot.schemas import LaserScan, Leg, PersonCandidates

from .clusters import LegSet
from .message import candidates_message, leg_list, person

#: Pairing rules (``pairing`` settings): the thesis's greedy one, or the best matching.
PAIRINGS = ("closest_first", "matching")

#: Beyond this many legs within reach of each other, ``matching`` falls back to closest first
#: (the exact search grows exponentially; a scan's group of touching legs is 2-6).
MAX_MATCHED_GROUP = 12


class Anchor(NamedTuple):
    """Where the tracked target should be, for :func:`pair_legs` (``matching``) to prefer the
    grouping of legs that has a person there (beyond the thesis; the ``thesis`` detector's
    ``anchor_weight``)."""

    x_m: float
    y_m: float
    weight: float
    """Metres of pair weight (``max_distance_m - d``) one metre nearer the anchor is worth."""
    gate_m: float
    """Persons farther than this from the anchor count as this far (criterion 3's gate): far
    from the target, the anchor prefers nothing."""
    lone_leg_m: float
    """A lone leg's distance to the anchor counts this much less: a person's centre lies
    about half a stride from a leg seen alone."""


def pair_legs(
    x: list[float],
    y: list[float],
    max_distance_m: float,
    pairing: str = "closest_first",
    anchor: Anchor | None = None,
) -> list[tuple[int, ...]]:
    """Group legs into persons, each leg used once; ``(i, j)`` for two legs closer than
    ``max_distance_m`` and ``(i,)`` for a lone leg, ordered by their first leg.

    ``closest_first`` (thesis 4.3.3): the closest pair first, then the closest of the rest.
    ``matching`` (beyond the thesis): the pairing that maximises the sum over pairs of
    ``max_distance_m - d``, i.e. every pair counts, the tighter the better. Two people walking
    0.35 m apart show four legs where an inner leg of each is closer to the other person's
    than to its own partner: closest first pairs the two inner legs into a phantom person
    between them and leaves the outer legs alone; the matching keeps both people. Exact per
    group of legs within reach of each other (up to :data:`MAX_MATCHED_GROUP` legs).

    ``anchor`` (``matching`` only): the tracked target's predicted position. The grouping then
    maximises the pair weights minus ``anchor.weight`` times the distance from the anchor to
    the nearest person of the grouping (see :class:`Anchor`). When a passer-by walks just in
    front of the target, the target's far leg is hidden behind the passer-by's near leg, and
    that leg is often closer to the target's near leg than to the passer-by's far leg: the
    matching alone then pairs the two people's near legs (a cross pair ~0.2 m off the target,
    towards the passer-by); with the anchor it keeps the passer-by's legs together and the
    target's near leg alone, where the target is.

    Plain Python: a scan has a handful of legs, and numpy's per-call cost would dominate.
    """
    k = len(x)
    pairs = []
    for i in range(k):
        xi, yi = x[i], y[i]
        for j in range(i + 1, k):
            d = math.hypot(x[j] - xi, y[j] - yi)
            if d < max_distance_m:
                pairs.append((d, i, j))
    if pairing not in PAIRINGS:
        raise ValueError(f"pairing must be one of {PAIRINGS}, not {pairing!r}")
    ends = [i for _, i, _ in pairs] + [j for _, _, j in pairs]
    if len(set(ends)) == len(ends):
        # no leg with two partners in reach: every rule (and every anchor) pairs them all
        chosen = [(i, j) for _, i, j in pairs]
    elif pairing == "matching":
        chosen = _best_matching(k, pairs, max_distance_m)
        if anchor is not None:
            chosen = _anchored(x, y, k, pairs, chosen, max_distance_m, anchor)
    else:
        chosen = _closest_first(k, sorted(pairs))
    paired = {i for pair in chosen for i in pair}
    return sorted([*chosen, *((i,) for i in range(k) if i not in paired)])


#: Most legs near the anchor whose groupings :func:`pair_legs` enumerates (an anchor among
#: more leaves the plain matching; 8 legs have at most 764 groupings, a scan's 2-4 a handful).
MAX_ANCHORED_LEGS = 8


def _anchored(
    x: list[float],
    y: list[float],
    k: int,
    pairs: list[tuple[float, int, int]],
    chosen: list[tuple[int, int]],
    max_distance_m: float,
    a: Anchor,
) -> list[tuple[int, int]]:
    """The grouping maximising the pair weights minus ``a.weight`` times the distance from the
    anchor to its nearest person (capped at ``a.gate_m``), among those with at least as many
    pairs as ``chosen`` (the plain best matching), which stays unless another grouping scores
    higher. The anchor only chooses *which* legs pair, never fewer pairs: splitting a person's
    own two legs because the prediction lags towards one of them biased every track (RMSE up
    in all 15 scenarios).

    Exact: every grouping of the legs within reach (transitively) of a leg that can belong to
    a person inside the gate is scored; the other legs keep ``chosen``'s grouping. More than
    :data:`MAX_ANCHORED_LEGS` such legs, or none with two partners in reach (no other
    grouping then has as many pairs): ``chosen``."""
    weight = {(i, j): max_distance_m - d for d, i, j in pairs}
    near: list[list[int]] = [[] for _ in range(k)]
    for _, i, j in pairs:
        near[i].append(j)
        near[j].append(i)

    def cost(person: tuple[int, ...]) -> float:
        if len(person) == 2:
            i, j = person
            d = math.hypot((x[i] + x[j]) / 2 - a.x_m, (y[i] + y[j]) / 2 - a.y_m)
        else:
            d = max(0.0, math.hypot(x[person[0]] - a.x_m, y[person[0]] - a.y_m) - a.lone_leg_m)
        return min(d, a.gate_m)

    # the legs whose grouping can put a person inside the gate, and all legs in reach of them
    reach = a.gate_m + max(max_distance_m / 2, a.lone_leg_m)
    todo = [i for i in range(k) if math.hypot(x[i] - a.x_m, y[i] - a.y_m) < reach]
    group = set(todo)
    while todo:
        for j in near[todo.pop()]:
            if j not in group:
                group.add(j)
                todo.append(j)
    if len(group) > MAX_ANCHORED_LEGS or all(len(near[i]) < 2 for i in group):
        return chosen
    outside = [g for g in chosen if g[0] not in group]
    paired = {i for g in chosen for i in g}
    rest = [*outside, *((i,) for i in range(k) if i not in group and i not in paired)]
    nearest_outside = min((cost(g) for g in rest), default=a.gate_m)
    inside = [g for g in chosen if g[0] in group]

    def value(groups: list[tuple[int, int]]) -> float:
        legs = {i for g in groups for i in g}
        lone = [(i,) for i in group if i not in legs]
        nearest = min([nearest_outside, *(cost(g) for g in groups), *(cost(g) for g in lone)])
        return sum(weight[g] for g in groups) - a.weight * nearest

    def groupings(free: list[int]):
        """Every grouping of the legs ``free`` (ascending) into pairs in reach and lone legs."""
        if not free:
            yield []
            return
        i, others = free[0], free[1:]
        yield from groupings(others)  # i alone
        for j in near[i]:
            if j in others:
                for g in groupings([m for m in others if m != j]):
                    yield [(i, j), *g]

    best, best_value = inside, value(inside)
    for g in groupings(sorted(group)):
        if len(g) >= len(inside):
            v = value(g)
            if v > best_value + 1e-12:
                best, best_value = g, v
    return [*outside, *best]


def _closest_first(k: int, pairs: list[tuple[float, int, int]]) -> list[tuple[int, int]]:
    used = [False] * k
    out = []
    for _, i, j in pairs:
        if not used[i] and not used[j]:
            used[i] = used[j] = True
            out.append((i, j))
    return out


def _best_matching(
    k: int, pairs: list[tuple[float, int, int]], max_distance_m: float
) -> list[tuple[int, int]]:
    """Maximum-weight matching (weight ``max_distance_m - d``), exact per connected group."""
    near: list[list[tuple[int, float]]] = [[] for _ in range(k)]
    for d, i, j in pairs:
        w = max_distance_m - d
        near[i].append((j, w))
        near[j].append((i, w))
    seen = [False] * k
    out: list[tuple[int, int]] = []
    for root in range(k):
        if seen[root] or not near[root]:
            continue
        group, stack = [], [root]  # the legs within reach of root, transitively
        seen[root] = True
        while stack:
            i = stack.pop()
            group.append(i)
            for j, _ in near[i]:
                if not seen[j]:
                    seen[j] = True
                    stack.append(j)
        if len(group) > MAX_MATCHED_GROUP:
            inside = set(group)
            out += _closest_first(k, sorted(p for p in pairs if p[1] in inside))
            continue
        out += _match_group(sorted(group), near)
    return out


def _match_group(
    group: list[int], near: list[list[tuple[int, float]]]
) -> tuple[tuple[int, int], ...]:
    """The best matching of one group of legs: each leg, lowest first, alone or paired."""
    if len(group) == 2:  # the common case: one pair
        return ((group[0], group[1]),)
    bit = {leg: b for b, leg in enumerate(group)}
    memo: dict[int, tuple[float, tuple[tuple[int, int], ...]]] = {0: (0.0, ())}

    def best(free: int) -> tuple[float, tuple[tuple[int, int], ...]]:
        if free in memo:
            return memo[free]
        b = (free & -free).bit_length() - 1  # the lowest free leg: alone, or paired
        rest = free & ~(1 << b)
        score, chosen = best(rest)
        i = group[b]
        for j, w in near[i]:
            if free >> bit[j] & 1:
                sub, sub_chosen = best(rest & ~(1 << bit[j]))
                if sub + w > score:
                    score, chosen = sub + w, ((min(i, j), max(i, j)), *sub_chosen)
        memo[free] = score, chosen
        return score, chosen

    return best((1 << len(group)) - 1)[1]


def paired_candidates(
    scan: LaserScan,
    detector: str,
    legs: LegSet | list[Leg],
    pair_distance_m: float,
    two_leg_confidence: float,
    one_leg_confidence: float,
    partner: Callable[[list[Leg], int], Leg | None] | None = None,
    pairing: str = "closest_first",
    anchor: Anchor | None = None,
) -> PersonCandidates:
    """Pair ``legs`` (thesis 4.3.3) and wrap the persons as the wire message. ``partner``:
    given the legs and a lone leg's index, another leg to pair it with, or None (a detector
    that finds legs the pairing cannot, e.g. a half-hidden one); ``pairing``: see
    :func:`pair_legs`, as ``anchor``. ``legs`` as wire structs are used as they are (not
    copied)."""
    wire = legs if isinstance(legs, list) else leg_list(legs)
    groups = pair_legs(
        [w.x_m for w in wire], [w.y_m for w in wire], pair_distance_m, pairing, anchor
    )
    out = []
    for g in groups:
        other = None if len(g) == 2 or partner is None else partner(wire, g[0])
        if len(g) == 2:
            out.append(person([wire[i] for i in g], "two_legs", two_leg_confidence))
        elif other is not None:
            out.append(person([wire[g[0]], other], "two_legs", two_leg_confidence))
        else:
            out.append(person([wire[g[0]]], "one_leg", one_leg_confidence))
    return candidates_message(scan, detector, out)
