"""Reading CARMEN robot logs (``.log``, ``.clf``, gzipped or not) as followbot messages.

A CARMEN log is text, one message a line: ``NAME fields... timestamp hostname
logger_timestamp``. The records read (docs/recording.md, "CARMEN logs"):

==========================  =====================================================================
record                      fields before ``timestamp hostname logger_timestamp``
==========================  =====================================================================
``ODOM``                    ``x y theta tv rv accel``
``FLASER``, ``RLASER``      ``n r1..rn x y theta odom_x odom_y odom_theta`` (front, rear laser)
``LASER3``, ``LASER4``      ``n r1..rn``
``RAWLASER1..4``            ``laser_type start_angle fov angular_resolution maximum_range accuracy
                            remission_mode n r1..rn m e1..em``
``ROBOTLASER1``, ``2``      as RAWLASER, then ``laser_x laser_y laser_theta robot_x robot_y
                            robot_theta tv rv forward_safety_dist side_safety_dist turn_axis``
==========================  =====================================================================

A *source* is a record name (``FLASER``) giving LaserScan or Odometry, or ``NAME/odom``: the
odometry fields of a laser record (``odom_*`` of FLASER, ``robot_*`` with ``tv rv`` of
ROBOTLASER) as Odometry stamped with its scan. Stamps are ``timestamp`` in integer ns.

Beam geometry: RAWLASER and ROBOTLASER give theirs (beam ``i`` at ``start_angle + i *
angular_resolution``, readings at or beyond ``maximum_range`` mean no return). The older
records do not: their ``n`` beams cover 180 deg counter-clockwise from -90 deg (right), both
ends included for odd ``n`` (181: 1 deg, 361: 0.5 deg) and the +90 deg end left out for even
``n`` (180: 1 deg, 360: 0.5 deg), the choice that fits the logs' corrected poses best
(measured in docs/recording.md). Their no-return reading is the scanner's ceiling: 80 m
(CARMEN's maximum for these records), or lower where the file's readings pile up at a lower
maximum (:data:`CEILING_MIN_M`).

The file is read twice. :class:`CarmenLog` reads it once on opening: what it holds, the
malformed lines (:class:`SkippedLines`), each laser's ceiling and whether its stamps can be
used; :meth:`CarmenLog.messages` then reads it again, in stamp order.
"""

from __future__ import annotations

import gzip
import heapq
import math
import re
import zlib
from array import array
from collections import Counter
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from decimal import Decimal, DecimalException
from pathlib import Path

import numpy as np

from followbot.mcapio import Damage
from followbot.schemas import MAX_BEAMS, LaserScan, Message, Odometry

__all__ = [
    "CARMEN_SUFFIXES",
    "DEFAULT_SCAN_SOURCES",
    "CarmenLog",
    "Malformed",
    "Record",
    "SkippedLines",
    "flaser_geometry",
    "looks_like_carmen",
    "parse_line",
]

#: File names read as CARMEN logs (besides any file whose first lines are CARMEN records).
CARMEN_SUFFIXES = (".log", ".log.gz", ".clf", ".clf.gz")

#: Which laser feeds sensors/scan by default, first present wins: the front laser, as
#: ROBOTLASER1 (newer logs), FLASER (older ones) or RAWLASER1 (without the robot's pose). A log
#: with none of them and a single other laser uses that one.
DEFAULT_SCAN_SOURCES = ("ROBOTLASER1", "FLASER", "RAWLASER1")

#: The maximum CARMEN gives FLASER-type records (its reader's ``maximum_range``): readings at
#: or beyond it mean no return (SICK scanners write 81.83-81.91 m for it).
CARMEN_MAX_RANGE_M = 80.0
#: A FLASER-type laser whose readings pile up at a lower maximum (some converters wrote 50 m,
#: 51.15 m, 32.767 m for "no return") has that ceiling: when at least one reading per
#: ``CEILING_PER_SCANS`` scans lies within ``CEILING_BAND_M`` of the file's largest reading,
#: readings from there up mean no return. A ceiling is only looked for from CEILING_MIN_M up: an
#: indoor scan's farthest wall repeats too, and must not turn into "no return".
CEILING_MIN_M = 20.0
CEILING_BAND_M = 0.1
CEILING_PER_SCANS = 10

#: A laser whose scans are stamped 0 or no later than an earlier scan more often than this (a
#: fraction of its scans) has an unusable clock: its scans are restamped RESTAMP_PERIOD_NS
#: apart, in file order. Below it, only those scans are left out.
CLOCK_BROKEN_FRACTION = 0.1
RESTAMP_PERIOD_NS = 1_000_000_000

#: Records known but not converted (no followbot message carries them).
NOT_CONVERTED = {
    "PARAM": "parameters",
    "SYNC": "sync marks",
    "TRUEPOS": "simulator true pose",
    "NMEAGGA": "GPS",
    "NMEARMC": "GPS",
    "GPSNMEA": "GPS",
    "POSITIONLASER": "laser mount",
    "SONAR": "sonar",
    "BUMPER": "bumpers",
}

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")
_FLASER_TYPE = {"FLASER": "front_laser", "RLASER": "rear_laser", "LASER3": "laser3",
                "LASER4": "laser4"}  # fmt: skip
_RAW_TYPE = {f"RAWLASER{i}": f"laser{i}" for i in range(1, 5)}
_ROBOT_TYPE = {"ROBOTLASER1": "laser1", "ROBOTLASER2": "laser2"}
_WITH_POSE = {"FLASER", "RLASER", "ROBOTLASER1", "ROBOTLASER2"}
_BIG = 1e12  # |x| a followbot Finite field accepts
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_MAX_STAMP_S = Decimal(2**63 - 1).scaleb(-9)  # a followbot stamp is an int64 of ns
_SHOWN_LINES = 5


def flaser_geometry(n: int) -> tuple[float, float]:
    """``(angle_min_rad, angle_increment_rad)`` of an ``n``-beam FLASER, RLASER, LASER3/4 scan.

    180 deg counter-clockwise from -90 deg: odd ``n`` has both ends (181 beams: 1 deg), even
    ``n`` leaves the +90 deg end out (180 beams: 1 deg, the last beam at +89 deg).
    """
    if n <= 1:
        return -math.pi / 2, math.pi
    return -math.pi / 2, math.pi / (n - 1) if n % 2 else math.pi / n


# ----------------------------------------------------------------------------- lines


class Malformed(ValueError):
    """A line that cannot be read: ``reason`` (counted) and ``detail`` (an example shown)."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(reason)
        self.reason = reason
        self.detail = detail


@dataclass
class Record:
    """One readable laser or odometry line (:func:`parse_line`)."""

    name: str
    stamp_ns: int
    ranges: np.ndarray | None = None  # float64, metres
    angle_min_rad: float = 0.0
    angle_increment_rad: float = 0.0
    max_range_m: float | None = None  # None: a FLASER-type record, the file's ceiling applies
    remissions: np.ndarray | None = None
    odom: tuple[float, float, float, float, float] | None = None  # x y yaw v w
    laser_pose: tuple[float, float, float] | None = None  # x y yaw of the laser (FLASER x y theta)


def _numbers(tokens: list[str], start: int, stop: int, name: str) -> np.ndarray:
    try:
        values = np.array(tokens[start:stop], dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens[start:stop] if not _is_float(t))
        raise Malformed("not a number", f"{name}: {bad[:20]!r}") from None
    if not np.isfinite(values).all():
        i = int(np.flatnonzero(~np.isfinite(values))[0])
        raise Malformed("not a finite number", f"{name}: {tokens[start + i][:20]!r}")
    return values


def _floats(tokens: list[str], start: int, stop: int, name: str) -> list[float]:
    """As :func:`_numbers`, for a few fields (Python floats are faster there)."""
    try:
        values = [float(t) for t in tokens[start:stop]]
    except ValueError:
        bad = next(t for t in tokens[start:stop] if not _is_float(t))
        raise Malformed("not a number", f"{name}: {bad[:20]!r}") from None
    for t, v in zip(tokens[start:stop], values, strict=True):
        if not math.isfinite(v):
            raise Malformed("not a finite number", f"{name}: {t[:20]!r}")
    return values


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _count(tokens: list[str], i: int, name: str, what: str) -> int:
    if i >= len(tokens):
        raise Malformed("truncated", f"{name}: ends before its {what}")
    text = tokens[i]
    if not (text.isascii() and text.isdigit()):
        raise Malformed("bad count", f"{name}: {what} {text[:20]!r}")
    return int(text)


def _stamp_ns(text: str, name: str) -> int:
    """``timestamp`` (seconds, decimal or exponent notation) as integer ns, exactly."""
    try:
        seconds = Decimal(text)
    except DecimalException:
        seconds = Decimal("NaN")
    if not seconds.is_finite():
        raise Malformed("bad timestamp", f"{name}: {text[:20]!r}")
    if seconds < 0:
        raise Malformed("bad timestamp", f"{name}: {text[:20]!r} (negative)")
    ns = int(seconds.scaleb(9).to_integral_value()) if seconds <= _MAX_STAMP_S else 2**63
    if ns >= 2**63:  # compared before converting: 1e999999 would take long
        raise Malformed("bad timestamp", f"{name}: {text[:20]!r} (too large)")
    return ns


def _tail(tokens: list[str], i: int, name: str, needs: str) -> int:
    """Check ``timestamp hostname [logger_timestamp]`` end the line at ``i``; the stamp."""
    left = len(tokens) - i
    if left < 2:
        raise Malformed("truncated", f"{name}: {len(tokens)} fields, {needs} needs {i + 2} or more")
    if left > 3:
        raise Malformed(
            "too many fields", f"{name}: {len(tokens)} fields, {needs} has at most {i + 3}"
        )
    return _stamp_ns(tokens[i], name)


def _pose(values, name: str) -> tuple[float, float, float]:
    x, y, theta = float(values[0]), float(values[1]), float(values[2])
    if abs(x) > _BIG or abs(y) > _BIG:
        raise Malformed("out of range", f"{name}: position ({x:g}, {y:g})")
    return x, y, math.remainder(theta, 2 * math.pi)


def _speed(v: float, name: str) -> float:
    if abs(v) > _BIG:
        raise Malformed("out of range", f"{name}: speed {v:g}")
    return v


def parse_line(tokens: list[str]) -> Record:
    """One laser or odometry line (its fields, name first) read and checked; raises
    :class:`Malformed` saying why not."""
    name = tokens[0]
    if name == "ODOM":
        if len(tokens) < 9:
            raise Malformed("truncated", f"ODOM: {len(tokens)} fields, needs 9 or more")
        v = _floats(tokens, 1, 7, name)
        stamp = _tail(tokens, 7, name, "ODOM")
        x, y, yaw = _pose(v[0:3], name)
        return Record(name, stamp, odom=(x, y, yaw, _speed(v[3], name), _speed(v[4], name)))
    if name in _FLASER_TYPE:
        n = _beams(tokens, 1, name)
        extra = 6 if name in _WITH_POSE else 0
        needs = f"a {name} of {n} beams"
        if len(tokens) < 2 + n + extra + 2:
            need = 2 + n + extra + 2
            raise Malformed("truncated", f"{name}: {len(tokens)} fields, {needs} needs {need}")
        values = _numbers(tokens, 2, 2 + n + extra, name)
        stamp = _tail(tokens, 2 + n + extra, name, needs)
        angle_min, step = flaser_geometry(n)
        rec = Record(name, stamp, values[:n], angle_min, step)
        if extra:
            rec.laser_pose = _pose(values[n : n + 3], name)
            x, y, yaw = _pose(values[n + 3 : n + 6], name)  # odom_x odom_y odom_theta
            rec.odom = (x, y, yaw, 0.0, 0.0)
        return rec
    if name in _RAW_TYPE or name in _ROBOT_TYPE:
        if len(tokens) < 9:
            raise Malformed("truncated", f"{name}: {len(tokens)} fields, ends in its laser config")
        config = _floats(tokens, 1, 8, name)
        _type, start, _fov, step, max_range, _accuracy, _mode = config
        n = _beams(tokens, 8, name)
        ranges = _numbers(tokens, 9, min(9 + n, len(tokens)), name)
        if len(ranges) < n:
            raise Malformed("truncated", f"{name}: {len(tokens)} fields, ends in its {n} ranges")
        m = _count(tokens, 9 + n, name, "remission count")
        i = 10 + n + m
        remissions = _numbers(tokens, 10 + n, min(i, len(tokens)), name)
        if np.abs(remissions).max(initial=0.0) > _FLOAT32_MAX:  # sent as float32
            raise Malformed("out of range", f"{name}: a remission beyond float32")
        if len(remissions) < m:
            raise Malformed(
                "truncated", f"{name}: {len(tokens)} fields, ends in its {m} remissions"
            )
        if not (abs(start) <= 2 * math.pi and 0 < max_range <= _BIG):
            why = f"{name}: start_angle {start:g}, maximum_range {max_range:g}"
            raise Malformed("bad laser config", why)
        if (step == 0 and n > 1) or abs(step) > math.pi or abs(step) * (n - 1) > 2 * math.pi:
            raise Malformed("bad laser config", f"{name}: {n} beams of {step:g} rad")
        rec = Record(name, 0, ranges, start, step, max_range, remissions if m == n else None)
        needs = f"a {name} of {n} ranges and {m} remissions"
        if name in _ROBOT_TYPE:
            if len(tokens) < i + 11 + 2:
                raise Malformed(
                    "truncated", f"{name}: {len(tokens)} fields, {needs} needs {i + 13}"
                )
            pose = _floats(tokens, i, i + 11, name)
            rec.laser_pose = _pose(pose[0:3], name)
            x, y, yaw = _pose(pose[3:6], name)  # robot_x robot_y robot_theta
            rec.odom = (x, y, yaw, _speed(pose[6], name), _speed(pose[7], name))
            i += 11
        rec.stamp_ns = _tail(tokens, i, name, needs)
        return rec
    raise Malformed("not a laser or odometry record", f"{name[:20]!r}")


def _beams(tokens: list[str], i: int, name: str) -> int:
    n = _count(tokens, i, name, "beam count")
    if not 1 <= n <= MAX_BEAMS:
        raise Malformed("bad count", f"{name}: {n} beams (reads 1 to {MAX_BEAMS})")
    return n


def _kind(name: str) -> str:
    """``"scan"`` (a laser record), ``"odom"``, ``"other"`` (known, not converted) or
    ``"unknown"``."""
    if name in _FLASER_TYPE or name in _RAW_TYPE or name in _ROBOT_TYPE:
        return "scan"
    if name == "ODOM":
        return "odom"
    return "other" if name in NOT_CONVERTED else "unknown"


def _frame(name: str) -> str:
    return {**_FLASER_TYPE, **_RAW_TYPE, **_ROBOT_TYPE}[name]


# ----------------------------------------------------------------------------- reading


@dataclass
class SkippedLines:
    """Lines that could not be read, by reason, with the first line numbers of each."""

    lines_read: int = 0
    counts: Counter = field(default_factory=Counter)
    first: dict[str, list[int]] = field(default_factory=dict)
    example: dict[str, str] = field(default_factory=dict)

    def add(self, reason: str, detail: str, line_no: int) -> None:
        self.counts[reason] += 1
        shown = self.first.setdefault(reason, [])
        if len(shown) < _SHOWN_LINES:
            shown.append(line_no)
        self.example.setdefault(reason, detail)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def describe(self) -> str:
        parts = []
        for reason, n in self.counts.most_common():
            lines = ", ".join(map(str, self.first[reason]))
            more = ", ..." if n > len(self.first[reason]) else ""
            where = f"line{'s' if n > 1 else ''} {lines}{more}"
            parts.append(f"{n} {reason} ({where}; e.g. {self.example[reason]})")
        head = f"skipped {self.total} of {self.lines_read} lines it could not read"
        return f"{head}: {'; '.join(parts)}"


class CarmenLog:
    """A CARMEN log, read once on opening (see the module docstring).

    After opening: :attr:`contents` (source -> (type name, count)) of the sources it can
    give, :attr:`unknown` and :attr:`not_converted` (record name -> lines), :attr:`bad`
    (malformed lines), :attr:`damage` (a gzip stream cut short or corrupt: read up to there),
    :attr:`no_return_m` (each laser's no-return reading), :attr:`restamped` (lasers whose
    stamps were unusable: why) and :attr:`clock_ok` (False when any laser was restamped: the
    stamps of other records are then on a different clock).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.contents: dict[str, tuple[str, int]] = {}
        self.unknown: Counter = Counter()
        self.not_converted: Counter = Counter()
        self.bad = SkippedLines()
        self.damage: Damage | None = None
        self.no_return_m: dict[str, float] = {}
        self.restamped: dict[str, str] = {}
        # one entry per readable record, in file order: its record name, its stamp in the
        # file and the stamp it gets (-1: left out, see _settle_clock)
        self._names: list[str] = []
        self._name_id = array("b")
        self._stamps = array("q")
        self._line_nos = array("q")
        self._final: np.ndarray | None = None
        self._survey()

    @property
    def clock_ok(self) -> bool:
        return not self.restamped

    def source_type(self, source: str) -> str:
        return self.contents[source][0]

    def laser_mount(self, source: str) -> tuple[float, float, float] | None:
        """The laser's (x_m, y_m, yaw_rad) on the robot as ``source``'s records give it: a
        ROBOTLASER record carries the laser's pose and the robot's in one frame, so the laser's
        pose in the robot's frame is robot^-1 * laser (the first readable record's; the mount
        does not move). None for other records: FLASER's laser pose and odometry are in
        different frames in corrected logs."""
        if source not in _ROBOT_TYPE:
            return None
        for _line_no, tokens in self._lines():
            if tokens[0] != source:
                continue
            try:
                rec = parse_line(tokens)
            except Malformed:
                continue
            if rec.laser_pose is None or rec.odom is None:
                continue
            lx, ly, lyaw = rec.laser_pose
            rx, ry, ryaw = rec.odom[:3]
            c, s = math.cos(ryaw), math.sin(ryaw)
            dx, dy = lx - rx, ly - ry
            return c * dx + s * dy, -s * dx + c * dy, math.remainder(lyaw - ryaw, 2 * math.pi)
        return None

    # ------------------------------------------------------------------ first pass

    def _lines(self) -> Iterator[tuple[int, list[str]]]:
        """``(line number, fields)`` of each non-empty, non-comment line; a gzip stream that
        breaks sets :attr:`damage` (what was read before stays)."""
        opener = gzip.open if _is_gzip(self.path) else open
        line_no = 0
        try:
            with opener(self.path, "rt", encoding="latin-1", newline=None) as f:
                for line_no, line in enumerate(f, 1):
                    tokens = line.split()
                    if tokens and not tokens[0].startswith("#"):
                        yield line_no, tokens
        except (EOFError, OSError, zlib.error) as exc:
            if isinstance(exc, EOFError):
                why = (
                    f"the gzip stream ends early, after line {line_no}: the file was cut "
                    "short (an interrupted copy or download); the lines before were read"
                )
            else:
                why = f"unreadable gzip data after line {line_no} ({exc})"
            self._broken = why

    def _survey(self) -> None:
        self._broken = ""
        scans: Counter = Counter()
        high: dict[str, Counter] = {}  # FLASER-type source -> readings >= CEILING_MIN_M
        ids: dict[str, int] = {}
        first = last = None
        for line_no, tokens in self._lines():
            self.bad.lines_read = line_no
            name = tokens[0]
            kind = _kind(name)
            if kind == "other":
                self.not_converted[name] += 1
                continue
            if kind == "unknown":
                if _NAME.match(name):
                    self.unknown[name] += 1
                else:
                    self.bad.add("not a CARMEN record", f"{name[:20]!r}", line_no)
                continue
            try:
                rec = parse_line(tokens)
            except Malformed as bad:
                self.bad.add(bad.reason, bad.detail, line_no)
                continue
            if name not in ids:
                ids[name] = len(self._names)
                self._names.append(name)
            self._name_id.append(ids[name])
            self._stamps.append(rec.stamp_ns)
            self._line_nos.append(line_no)
            scans[name] += 1
            first = rec.stamp_ns if first is None else min(first, rec.stamp_ns)
            last = rec.stamp_ns if last is None else max(last, rec.stamp_ns)
            if rec.max_range_m is None and rec.ranges is not None:
                far = rec.ranges[rec.ranges >= CEILING_MIN_M]
                if far.size:
                    high.setdefault(name, Counter()).update(far.tolist())
        if self._broken:
            size = self.path.stat().st_size
            self.damage = Damage(self._broken, len(self._stamps), first, last, size)
        for name, n in scans.items():
            kind = "LaserScan" if _kind(name) == "scan" else "Odometry"
            self.contents[name] = (kind, n)
            if kind == "LaserScan" and name in _WITH_POSE:
                self.contents[f"{name}/odom"] = ("Odometry", n)
            if kind == "LaserScan" and name in _FLASER_TYPE:
                self.no_return_m[name] = _ceiling(high.get(name, Counter()), n)
        self._settle_clock()

    def _settle_clock(self) -> None:
        """Each record's stamp (:attr:`_final`): its own, except a laser's scans stamped 0 or
        no later than an earlier scan (left out, or all restamped when there are many) and
        odometry lines stamped 0 or no later than an earlier line (left out)."""
        ids = np.frombuffer(self._name_id, dtype=np.int8) if self._name_id else np.zeros(0, int)
        stamps = np.frombuffer(self._stamps, dtype=np.int64) if self._stamps else np.zeros(0, int)
        final = stamps.copy()
        for i, name in enumerate(self._names):
            rows = np.flatnonzero(ids == i)
            s = stamps[rows]
            # a stamp of 0 is no time (some logs hold lines the logger never stamped)
            ahead = (s > 0) & (s > np.maximum.accumulate(np.concatenate(([0], s[:-1]))))
            late = int((~ahead).sum())
            if _kind(name) == "scan" and late > CLOCK_BROKEN_FRACTION * len(rows):
                t0 = int(s[0]) if s[0] > 0 else RESTAMP_PERIOD_NS
                final[rows] = t0 + RESTAMP_PERIOD_NS * np.arange(len(rows), dtype=np.int64)
                self.restamped[name] = (
                    f"{late} of its {len(rows)} scans are stamped 0 or no later than an earlier "
                    f"scan (stamps {_seconds(s[0])}..{_seconds(s.max())} s); they are restamped "
                    f"{RESTAMP_PERIOD_NS / 1e9:g} s apart in file order"
                )
            else:
                final[rows[~ahead]] = -1
        self._final = final

    # ------------------------------------------------------------------ second pass

    def messages(
        self, sources: Collection[str], on_late: Callable[[str], None] | None = None
    ) -> Iterator[tuple[int, str, Message]]:
        """``(stamp_ns, source, message)`` of ``sources``, in stamp order (the odometry of a
        laser record just before its scan). ``on_late(record name)`` is called for each record
        of ``sources`` left out for its stamp (0, or no later than an earlier one), as it is
        read."""
        records = {s.removesuffix("/odom") for s in sources}
        wanted = np.array([name in records for name in self._names] or [False])
        ids = np.frombuffer(self._name_id, dtype=np.int8) if self._name_id else np.zeros(0, int)
        final = self._final
        keep = wanted[ids] & (final >= 0) if len(ids) else np.zeros(0, bool)
        # Stamps run back by at most `lag` against the newest before them (0 in a log written
        # in order): a message can go out once the newest stamp read is `lag` past it.
        kept = final[keep]
        lag = int((np.maximum.accumulate(kept) - kept).max()) if kept.size else 0
        heap: list = []
        newest = -1
        ordinal = 0  # of the next record read on opening
        line_nos, total = self._line_nos, len(final)
        for line_no, tokens in self._lines():
            while ordinal < total and line_nos[ordinal] < line_no:
                ordinal += 1
            if ordinal >= total:  # past the records read on opening (the file grew)
                break
            if line_nos[ordinal] != line_no:
                continue
            if not keep[ordinal]:
                if on_late is not None and wanted[ids[ordinal]]:
                    on_late(self._names[ids[ordinal]])
                ordinal += 1
                continue
            try:
                rec = parse_line(tokens)
            except Malformed:  # the file changed since it was opened
                continue
            stamp = int(final[ordinal])
            for n, (source, message) in enumerate(self._convert(rec, stamp, sources)):
                heapq.heappush(heap, (stamp, 2 * ordinal + n, source, message))
            ordinal += 1
            newest = max(newest, stamp)
            while heap and heap[0][0] <= newest - lag:
                stamp, _, source, message = heapq.heappop(heap)
                yield stamp, source, message
        while heap:
            stamp, _, source, message = heapq.heappop(heap)
            yield stamp, source, message

    def _convert(self, rec: Record, stamp: int, sources: Collection[str]):
        name = rec.name
        if rec.odom is not None and (name == "ODOM" or f"{name}/odom" in sources):
            x, y, yaw, v, w = rec.odom
            odom = Odometry(stamp_ns=stamp, frame_id="odom", x_m=x, y_m=y, yaw_rad=yaw,
                            v_mps=v, w_radps=w)  # fmt: skip
            yield (name if name == "ODOM" else f"{name}/odom"), odom
        if rec.ranges is not None and name in sources:
            limit = rec.max_range_m if rec.max_range_m is not None else self.no_return_m[name]
            # at or beyond the ceiling, or negative (which CARMEN does not define): no return
            ranges = rec.ranges
            ranges = np.where((ranges >= limit) | (ranges < 0), np.inf, ranges).astype(np.float32)
            intensities = None
            if rec.remissions is not None:
                intensities = rec.remissions.astype(np.float32)
            yield name, LaserScan.from_ranges(
                ranges, stamp_ns=stamp, frame_id=_frame(name),
                angle_min_rad=rec.angle_min_rad, angle_increment_rad=rec.angle_increment_rad,
                range_min_m=0.0, range_max_m=limit, intensities=intensities,
            )  # fmt: skip


def _ceiling(high: Counter, scans: int) -> float:
    """The no-return reading of a FLASER-type laser (see :data:`CEILING_MIN_M`)."""
    if not high:
        return CARMEN_MAX_RANGE_M
    top = max(high)
    piled = sum(n for r, n in high.items() if r >= top - CEILING_BAND_M)
    if piled * CEILING_PER_SCANS >= scans:
        return min(CARMEN_MAX_RANGE_M, round(top - CEILING_BAND_M, 6))
    return CARMEN_MAX_RANGE_M


def _seconds(ns) -> str:
    return f"{int(ns) / 1e9:.6f}".rstrip("0").rstrip(".")


def _is_gzip(path: Path) -> bool:
    with path.open("rb") as f:
        return f.read(2) == b"\x1f\x8b"


def looks_like_carmen(path: Path) -> bool:
    """The file (gzipped or not) starts like a CARMEN log: a ``# CARMEN`` comment, or a
    first record that is one of CARMEN's."""
    try:
        opener = gzip.open if _is_gzip(path) else open
        with opener(path, "rt", encoding="latin-1") as f:
            for _ in range(50):
                line = f.readline(4096)
                if not line:
                    return False
                if line.startswith("#"):
                    if "CARMEN" in line:
                        return True
                    continue
                name = line.split()[0] if line.split() else ""
                if name:
                    return _kind(name) in ("scan", "odom", "other")
    except (OSError, EOFError, zlib.error, UnicodeDecodeError):
        return False
    return False
