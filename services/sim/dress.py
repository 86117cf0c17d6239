"""Random clothes: plausible everyday outfits, and lookalikes dressed like someone else.

A person with ``dress: {style: pedestrian}`` gets an outfit drawn from the palettes below;
``dress: {style: lookalike, of: ID}`` gets person ID's outfit with each garment's colour moved a
little. Everything is drawn from a generator seeded by (scenario seed, person id), so the
draws do not depend on the order of the people or on who else is in the scenario.

The palettes follow what pedestrians wear (docs/realism.md "Camera" measures PETS 2009's
pedestrians: 87 % of tops dark, trousers 47 % dark, 34 % blue, 17 % grey; PETS is a winter
street in coats, so indoor tops here are lighter): mostly dark, grey and blue tops, a few
muted colours and no saturated primaries; trousers mostly dark or denim blue. Each drawn
colour is varied in brightness (x lognormal, sigma 0.12) and per channel (+- 6 grey levels
std), so two people of one class rarely match.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from .scenario import AppearanceSpec, DressSpec, PersonSpec

__all__ = ["TOPS", "TROUSERS", "dressed", "lookalike", "pedestrian"]

_Palette = dict[str, tuple[float, list[tuple[int, int, int]]]]

#: Tops: class -> (probability, RGB colours drawn uniformly within the class).
TOPS: _Palette = {
    "dark": (0.55, [(25, 25, 28), (45, 45, 50), (30, 35, 55), (50, 38, 30), (40, 48, 42)]),
    "neutral": (0.20, [(110, 110, 112), (170, 170, 172), (220, 220, 218), (185, 170, 145)]),
    "blue": (0.15, [(70, 95, 140), (45, 60, 110), (140, 165, 200)]),
    "colour": (
        0.10,
        [
            (110, 35, 45),
            (95, 100, 55),
            (180, 150, 60),
            (35, 90, 95),
            (150, 70, 45),
            (190, 120, 130),
        ],
    ),
}
#: Trousers, as :data:`TOPS`.
TROUSERS: _Palette = {
    "dark": (0.45, [(28, 28, 30), (50, 50, 55), (30, 35, 55)]),
    "blue": (0.35, [(55, 75, 115), (40, 52, 85), (100, 125, 160)]),
    "neutral": (0.15, [(100, 100, 105), (170, 155, 125)]),
    "colour": (0.05, [(85, 90, 55), (95, 70, 50)]),
}
_SKIN = [(240, 200, 170), (225, 180, 150), (195, 145, 110), (150, 105, 75), (100, 70, 50)]
_HAIR = [(30, 25, 20), (60, 40, 25), (110, 80, 50), (190, 160, 110), (150, 150, 150)]
_SHOES = [(25, 25, 25), (50, 40, 30), (200, 200, 200)]
_PATTERNS = (("plain", 0.8), ("stripes", 0.1), ("checks", 0.1))


def _pick(rng: np.random.Generator, items: list):
    return items[int(rng.integers(len(items)))]


def _vary(rng: np.random.Generator, rgb: tuple[int, int, int]) -> tuple[int, int, int]:
    """Brightness x lognormal(0.12) and +- 6 grey levels per channel."""
    k = math.exp(0.12 * float(rng.standard_normal()))
    noisy = np.asarray(rgb, dtype=float) * k + rng.normal(0.0, 6.0, 3)
    r, g, b = np.clip(np.rint(noisy), 0, 255).astype(int).tolist()
    return (r, g, b)


def _garment(rng: np.random.Generator, palette: _Palette) -> tuple[int, int, int]:
    classes = list(palette)
    p = np.array([palette[c][0] for c in classes])
    cls = classes[int(rng.choice(len(classes), p=p / p.sum()))]
    return _vary(rng, _pick(rng, palette[cls][1]))


def _body(rng: np.random.Generator) -> dict:
    """Height, build, skin, hair and shoes of a random adult."""
    return {
        "height_m": float(np.clip(rng.normal(1.72, 0.08), 1.5, 1.95)),
        "shoulder_width_m": float(np.clip(rng.normal(0.44, 0.03), 0.36, 0.52)),
        "skin_rgb": _pick(rng, _SKIN),
        "hair_rgb": _pick(rng, _HAIR),
        "shoes_rgb": _pick(rng, _SHOES),
    }


def pedestrian(rng: np.random.Generator) -> AppearanceSpec:
    """A plausible everyday outfit and body (module docstring)."""
    names, p = zip(*_PATTERNS, strict=True)
    return AppearanceSpec(
        shirt_rgb=_garment(rng, TOPS),
        trousers_rgb=_garment(rng, TROUSERS),
        pattern=names[int(rng.choice(len(names), p=np.asarray(p)))],
        **_body(rng),
    )


def _near(rng: np.random.Generator, rgb: tuple[int, int, int], spread: float):
    """``rgb`` moved by a random direction, length spread x U(0.5, 1), clipped to 0-255."""
    d = rng.standard_normal(3)
    d *= spread * rng.uniform(0.5, 1.0) / max(float(np.linalg.norm(d)), 1e-9)
    r, g, b = np.clip(np.rint(np.asarray(rgb, dtype=float) + d), 0, 255).astype(int).tolist()
    return (r, g, b)


def lookalike(rng: np.random.Generator, like: AppearanceSpec, spread: float) -> AppearanceSpec:
    """Dressed like ``like``: each garment's colour moved by up to ``spread`` grey levels, the
    same pattern; own body, skin and hair."""
    return AppearanceSpec(
        shirt_rgb=_near(rng, like.shirt_rgb, spread),
        trousers_rgb=_near(rng, like.trousers_rgb, spread),
        pattern=like.pattern,
        **_body(rng),
    )


def dressed(people: list[PersonSpec], seed: int) -> dict[int, AppearanceSpec]:
    """Each person's appearance by id: ``appearance`` as written, or drawn by ``dress``
    (originals first, then their lookalikes; the scenario checked the ``of`` links)."""
    out = {p.id: p.appearance for p in people}
    for p in sorted(people, key=lambda q: q.dress is not None and q.dress.style == "lookalike"):
        d: DressSpec | None = p.dress
        if d is None:
            continue
        rng = np.random.default_rng([seed, p.id, 36])
        if d.style == "pedestrian":
            out[p.id] = pedestrian(rng)
        else:
            out[p.id] = lookalike(rng, out[d.of], d.colour_spread)
    return out


def with_appearance(person: PersonSpec, look: AppearanceSpec) -> PersonSpec:
    """``person`` wearing ``look`` (and no dress left to draw)."""
    return msgspec.structs.replace(person, appearance=look, dress=None)
