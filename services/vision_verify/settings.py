"""vision_verify's settings, and the settings that were removed or renamed (a file naming one is
refused with the reason or the new key: services/runtime/settings.py ``retired_settings``).

The settings of one role are nested under its name -- ``occlusion`` (what hides a candidate),
``acquire`` (learning a model from a lone mover), ``files`` (saved models), ``recovery``
(getting the model back from the network), ``learn`` (a verifier that learns online) --
``--set occlusion.laser_margin_m=0.4``, or in a file ``occlusion: {laser_margin_m: 0.4}``.
Pairing scans with images, the verifier and the cameras are top-level.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

import msgspec

from followbot.services.runtime.settings import NodeSettings, removed, renamed

from .core import Camera
from .model import MAX_MODEL_BYTES, AcquireSettings

__all__ = [
    "RETIRED_SETTINGS",
    "FileSettings",
    "LearnSettings",
    "OcclusionSettings",
    "RecoverySettings",
    "VisionVerifySettings",
]

_Pos = Annotated[float, msgspec.Meta(gt=0)]

_LOG = "docs/tracker_log.md"

#: Settings that are gone or moved: a file or --set naming one is refused with this.
RETIRED_SETTINGS: dict[str, str] = {
    "adapt_rate": removed(
        f"blending confident matches into the model, measured and left off, see {_LOG}; "
        "verifier: online learns from the tracker's target"
    ),
    "adapt_publish_period_s": removed("it only applied with adapt_rate, also removed"),
    "adapt_max_distance": renamed("learn.confident_max_distance"),
    "adapt_margin": renamed("learn.confident_margin"),
    "learn_from": renamed("learn.source"),
    "learn_gate_m": renamed("learn.gate_m"),
    "learn_scans": renamed("learn.scans"),
    "min_visible_fraction": renamed("occlusion.min_visible_fraction"),
    "occlusion_margin_m": renamed("occlusion.laser_margin_m"),
    "occluder_half_width_m": renamed("occlusion.laser_half_width_m"),
    "occlusion_abstain_fraction": renamed("occlusion.laser_abstain_fraction"),
    "auto_acquire": renamed("acquire.auto"),
    "acquire_timeout_s": renamed("acquire.timeout_s"),
    "models_dir": renamed("files.folder"),
    "model_file": renamed("files.default_name"),
    "max_model_bytes": renamed("files.max_bytes"),
    "query_model_on_start": renamed("recovery.query_on_start"),
    "query_timeout_s": renamed("recovery.query_timeout_s"),
    "query_period_s": renamed("recovery.query_period_s"),
    "model_holder": renamed("recovery.holder"),
    "recover_wait_s": renamed("recovery.holder_wait_s"),
}


class OcclusionSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What hides a candidate from the camera (beyond the thesis, which judges whole
    rectangles): ``--set occlusion.min_visible_fraction=0.6``."""

    min_visible_fraction: Annotated[float, msgspec.Meta(ge=0, le=1)] | None = 0.5
    """The columns of a candidate's rectangle that nearer candidates' rectangles cover are not
    its own (the laser gives the depth order). A candidate is judged on the widest run of
    columns left, and skipped as ``occluded`` (counted) when that run is under this fraction
    of its width. None: judge whole rectangles, as the thesis."""
    laser_margin_m: Annotated[float, msgspec.Meta(ge=0)] | None = 0.3
    """What the laser sees in front of a candidate. The detector reports only people near the
    target (thesis criterion 3), so a passer-by walking between the camera and the target is
    no candidate, and its pixels would be judged as the target's. A leg-like return of the
    candidates message's ``horizon`` (core.horizon_covers: a narrow run standing in front of
    its neighbours; walls and pillars are not) more than this nearer than a candidate stands
    for a body ``laser_half_width_m`` either side; what it covers is used as
    ``laser_abstain_fraction`` says. None: candidates' rectangles only."""
    laser_half_width_m: Annotated[float, msgspec.Meta(ge=0, le=2)] = 0.2
    """With laser_margin_m: the half width (m) of the body a leg-like return in front of a
    candidate stands for."""
    laser_abstain_fraction: Annotated[float, msgspec.Meta(gt=0, le=1)] | None = 0.25
    """With laser_margin_m: the whole rectangle is judged, and a candidate is reported
    unjudged only when it would be rejected and those returns cover at least this share of its
    columns: a view with someone unreported in front of it is trusted when it matches, not
    when it rejects (the tracker then counts no rejection). None: cut the covered columns from
    the rectangle, as nearer candidates' (min_visible_fraction). Default from the closed-loop
    runs of docs/tracker_log.md."""


class FileSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The folder of the model files that save/load commands name: ``--set files.folder=DIR``."""

    folder: str = ""
    """Folder of the files that save/load commands name; nothing outside it is read or
    written. "": $XDG_DATA_HOME/followbot/models (~/.local/share/followbot/models). A
    relative path is taken from the working directory at start."""
    default_name: str = "target.model"
    """Name (a file of the folder) for save/load commands that name none; "": none."""
    max_bytes: Annotated[int, msgspec.Meta(ge=1024, le=1 << 30)] = MAX_MODEL_BYTES
    """Largest model file saved or loaded, and largest model (its features) taken from the
    network."""


class RecoverySettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Getting the model back from the network after a restart (docs/vision_verify.md
    "Recovery after a restart"): ``--set recovery.holder=tracker``."""

    query_on_start: bool = True
    """Ask the network for the model on start, and again every query_period_s while there
    is none (until one is installed or a reset command drops it)."""
    query_timeout_s: _Pos = 1.0
    """How long one query waits for answers."""
    query_period_s: _Pos = 1.0
    """Seconds between two queries for the model while this service has none."""
    holder: str = "tracker"
    """The service that keeps the model for a restarted worker (the tracker serves the last
    model it got): once its liveliness is seen, a query it does not answer means it holds
    none. "": no such service."""
    holder_wait_s: _Pos = 3.0
    """With acquire.auto and the holder not seen alive: how long after start a query still
    counts as possibly missing a holder (nobody holds a model is concluded only from a query
    sent later)."""


class LearnSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Which candidate a verifier that learns online (``online``) learns as the target, all
    others in view being bystanders: ``--set learn.source=confident``."""

    source: Literal["tracker", "confident", "off"] = "tracker"
    """Which candidate of a judged scan a verifier that learns online learns as the target
    (the others in view as bystanders). ``tracker``: the candidate the tracker's state for
    that scan (tracking/target, status tracking) lies on, within ``gate_m`` and with no other
    candidate that near;
    ``confident``: the verifier's own choice when confident (``confident_max_distance``,
    ``confident_margin``); ``off``: never."""
    gate_m: _Pos = 0.4
    """``source: tracker``: how near the tracker's target a candidate must lie to be it."""
    bystanders: Literal["people", "candidates"] = "people"
    """``source: tracker``: who is learnt as a bystander. ``people``: only the candidates on
    the tracker's other people (tracking/people, within ``gate_m`` of a track seen at that
    scan): the laser's clutter -- a chair, a door frame, a red cabinet -- is nobody, and
    learnt as a bystander it teaches the model that whatever looks like it is not the target.
    ``candidates``: every other candidate in view."""
    agree_max_distance: Annotated[float, msgspec.Meta(ge=0)] | None = 0.3
    """``source: tracker``: the tracker's target is learnt only when the verifier's own
    distance for it is at most this (online: p >= 0.7), so a person the tracker took by
    mistake is not learnt as the target, which would make the mistake look right from then
    on (docs/tracker_log.md "Issue 36"). None: whatever the tracker follows."""
    scans: Annotated[int, msgspec.Meta(ge=1, le=64)] = 8
    """``source: tracker``: judged scans kept waiting for the tracker's state of their stamp
    (it comes after the verification, which the tracker uses)."""
    confident_max_distance: Annotated[float, msgspec.Meta(ge=0)] = 0.4
    """``source: confident``: the chosen candidate is learnt only when its distance is at most
    this ..."""
    confident_margin: Annotated[float, msgspec.Meta(ge=0)] = 0.2
    """... and at least this much below every other candidate's."""


class VisionVerifySettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    retired_settings: ClassVar[dict[str, str]] = RETIRED_SETTINGS

    verifier: str = "histogram"
    """histogram (thesis), face (seed 002), meanshift (seed 003), or any installed plugin."""
    verifier_settings: dict[str, Any] = {}
    """The verifier's own settings (see its settings_type); unknown keys are errors."""
    cameras: dict[str, Camera] = msgspec.field(default_factory=lambda: {"default": Camera()})
    """Camera calibrations by the Image message's ``intrinsics_id``."""
    threshold: Annotated[float, msgspec.Meta(ge=0)] | None = None
    """Rejection threshold on the distance; None: the verifier's default."""
    reject: bool = True
    """False: always take the most alike candidate (the thesis's rule)."""
    pair_tolerance_s: Annotated[float, msgspec.Meta(ge=0)] = 0.06
    """A scan's candidates are judged on the image nearest their stamp, if that is within
    this (s); else the scan waits for one (or is dropped)."""
    max_lag_s: _Pos = 0.5
    """Scans further than this behind the newest one are dropped unjudged."""
    scan_buffer: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 32
    """At most this many candidates messages wait for their image; beyond, the oldest are
    dropped unjudged (counted as scan_stale)."""
    answer_every_scan: bool = False
    """Lock-step: publish exactly one verification per candidates message."""
    image_wait_s: _Pos = 0.2
    """Lock-step: how long a scan waits for an image before an empty answer."""
    min_rect_side_px: Annotated[int, msgspec.Meta(ge=2)] = 8
    """A candidate whose image rectangle (clipped to the image) has a side shorter than this
    (px) is not judged (too_small): too few pixels for a histogram."""
    max_rect_width_factor: _Pos = 3.0
    """Candidates whose rectangle is wider than this many image widths are skipped."""
    occlusion: OcclusionSettings = msgspec.field(default_factory=OcclusionSettings)
    """What hides a candidate: nearer candidates, and people the laser sees in front."""
    acquire: AcquireSettings = msgspec.field(default_factory=AcquireSettings)
    """Learning a model from the target moving alone in front of the still robot."""
    files: FileSettings = msgspec.field(default_factory=FileSettings)
    """Where save and load commands keep model files."""
    recovery: RecoverySettings = msgspec.field(default_factory=RecoverySettings)
    """Asking the network for the model a restarted worker lost."""
    learn: LearnSettings = msgspec.field(default_factory=LearnSettings)
    """What a verifier that learns online learns from."""
