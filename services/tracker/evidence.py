"""How vision's judgements decide which track is the target (``identity.vision_evidence``).

identity.py asks its evidence role four things after each late verification: is the target
dropped after a rejection that counts, does the track vision chose replace the target, may a
lost target be re-taken by the track vision chose, and how much a rejection just above the
threshold may be forgiven (``hysteresis``).

* ``votes`` (the default; tuned to the histogram verifier's distance): consecutive
  verifications. ``identity.reject_votes`` rejections in a row drop the target,
  ``identity.switch_votes`` preferences in a row move it, a lost target is re-taken on a
  distance at most ``identity.reacquire_max_distance``, and ``identity.reject_hysteresis``
  forgives rejections just above the threshold for a target surely held.
* ``probability`` (for a verifier whose output is a calibrated probability, e.g. ``online``):
  each track holds the sum of the log-odds ``log(p / (1 - p))`` of vision's judgements of its
  candidate, within +-``identity.evidence_cap``. A strong judgement counts more than a weak
  one, and one threshold means the same on any footage: the target is dropped when its sum
  falls to ``identity.evidence_veto``, the track vision chose replaces it at
  ``identity.evidence_switch`` (and above the target's own), and a lost target is re-taken
  at ``identity.evidence_reacquire``. The cap keeps old confirmations from outweighing fresh
  rejections (from the cap, four looks at p = 0.2 pass -2), and one look counts at most
  +-``identity.evidence_look_max`` (2: p 0.12 / 0.88): a verifier's probability is calibrated
  on people in view, and one look at a table the laser did not see in front of the target is
  not the end of it. A verifier that gives no
  probability counts as p = 0.75 at or below its threshold and 0.25 above (one vote each).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from followbot.schemas import Verification, VerifiedCandidate

from .settings import TrackerSettings

__all__ = ["EVIDENCE", "ProbabilityEvidence", "VoteEvidence", "candidate_probability"]

_UNCALIBRATED = 0.75  # the probability an uncalibrated accept (or 1 - it: reject) counts as
_P_FLOOR = 1e-4  # p is clipped to [floor, 1 - floor]: one look is worth at most ~9.2 log-odds


def candidate_probability(c: VerifiedCandidate, threshold: float | None) -> float | None:
    """P(target) of a judged candidate: the verifier's own, else one vote by its threshold;
    None when it was not judged."""
    if c.distance is None or not c.in_view:
        return None
    if c.probability is not None and math.isfinite(c.probability):
        return min(max(c.probability, _P_FLOOR), 1.0 - _P_FLOOR)
    if threshold is None:
        return None
    return _UNCALIBRATED if c.distance <= threshold else 1.0 - _UNCALIBRATED


class VoteEvidence:
    """Consecutive verifications (module doc)."""

    def __init__(self, settings: TrackerSettings) -> None:
        self.settings = settings.identity
        self.hysteresis = self.settings.reject_hysteresis
        self.vetoes = self.settings.reject_votes > 0
        self._rejects = 0  # consecutive verifications that rejected the target's candidate
        self._switch: tuple[int, int] = (-1, 0)  # (track preferred by vision, consecutive votes)

    def judged(self, v: Verification, assoc: Mapping[int, int], live: Mapping[int, object]) -> None:
        """Every applied verification, before the questions below (votes keep no per-track sum)."""

    def accepted(self) -> None:
        """Vision chose the target's own candidate at the scan it judged."""
        self._rejects = 0

    def chose_target(self) -> None:
        """Vision's choice is the target's track now."""
        self._switch = (-1, 0)

    def new_target(self) -> None:
        """Another track (or the first) became the target."""
        self._rejects = 0
        self._switch = (-1, 0)

    def rejected(self, target_id: int) -> bool:
        """One counted rejection of the target's candidate: True when the target goes."""
        self._rejects += 1
        if self._rejects >= self.settings.reject_votes:
            self._rejects = 0
            return True
        return False

    def prefers(self, tid: int, target_id: int) -> bool:
        """Vision chose track ``tid``, not the target: True when ``tid`` becomes the target."""
        prev, votes = self._switch
        votes = votes + 1 if prev == tid else 1
        self._switch = (tid, votes)
        return votes >= self.settings.switch_votes

    def vetoed(self, tid: int) -> bool:
        """Has vision's evidence ruled track ``tid`` out as the target (votes: the search's
        rejection count says it)?"""
        return False

    def may_reacquire(self, tid: int, distance: float | None, threshold: float | None) -> bool:
        """May vision's choice ``tid`` re-take a target lost earlier?"""
        limit = self.settings.reacquire_max_distance
        return limit is None or (distance is not None and distance <= limit)

    def forget(self) -> None:
        self._switch = (-1, 0)


class ProbabilityEvidence:
    """Summed log-odds per track (module doc)."""

    def __init__(self, settings: TrackerSettings) -> None:
        self.settings = settings.identity
        self.hysteresis = 0.0  # a distance margin means nothing on a probability
        self.vetoes = self.settings.reject_votes > 0
        self.log_odds: dict[int, float] = {}

    def judged(self, v: Verification, assoc: Mapping[int, int], live: Mapping[int, object]) -> None:
        cap = self.settings.evidence_cap
        seen: set[int] = set()
        for c in v.candidates:
            tid = assoc.get(c.index, -1)
            p = candidate_probability(c, v.threshold)
            if tid < 0 or tid in seen or p is None:
                continue  # a track's first judged candidate speaks for it
            seen.add(tid)
            most = self.settings.evidence_look_max
            look = min(most, max(-most, math.log(p / (1.0 - p))))
            total = self.log_odds.get(tid, 0.0) + look
            self.log_odds[tid] = min(cap, max(-cap, total))
        for tid in [t for t in self.log_odds if t not in live]:
            del self.log_odds[tid]

    def accepted(self) -> None:
        pass

    def chose_target(self) -> None:
        pass

    def new_target(self) -> None:
        pass

    def rejected(self, target_id: int) -> bool:
        return self.log_odds.get(target_id, 0.0) <= self.settings.evidence_veto

    def prefers(self, tid: int, target_id: int) -> bool:
        mine = self.log_odds.get(tid, 0.0)
        return mine >= self.settings.evidence_switch and mine > self.log_odds.get(target_id, 0.0)

    def vetoed(self, tid: int) -> bool:
        return self.log_odds.get(tid, 0.0) <= self.settings.evidence_veto

    def may_reacquire(self, tid: int, distance: float | None, threshold: float | None) -> bool:
        return self.log_odds.get(tid, 0.0) >= self.settings.evidence_reacquire

    def forget(self) -> None:
        pass


EVIDENCE = {"votes": VoteEvidence, "probability": ProbabilityEvidence}
