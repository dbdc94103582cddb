"""Message loss per topic: counted by the recorder (:class:`LossCounter`), stored in the bag's
``metadata.yaml`` (``custom_data`` :data:`LOSS_KEY`, JSON) and checked by every reader
(:func:`loss_warning`: above :data:`LOSS_THRESHOLD` a warning says how much and where).

What a topic should have carried is counted two ways; the larger count is the loss:

* **publisher sequence** (``sequence``): each publisher numbers what it publishes (DDS
  publication sequence number, rmw ``publication_sequence_number``); a jump of k + 1 between two
  messages of one publisher is k messages lost. Counts every topic, header or not (the duty
  commands).
* **stamps** (``stamps``): a message with a header (``joint_states``, ``armature``) carries its
  sample instant; the sample period is the median of the first :data:`PERIOD_SAMPLES` stamp
  steps, and a step of n periods (n ≥ 1.5, rounded) is n − 1 samples lost.

Loss before the first message the recorder received and after its last is not seen (nothing
tells it); the gaps are listed with their log times from the first message [s].
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from typing import Any

#: ``custom_data`` key of ``metadata.yaml`` holding the recorder's loss count (JSON, per topic).
LOSS_KEY = "aeropend.loss"
#: ``custom_data`` key naming the recorder node in every bag ``record`` makes.
RECORDER_KEY = "aeropend.recorder"
#: Readers warn when a topic lost more than this fraction of what it should have carried.
LOSS_THRESHOLD = 0.01
#: Stamp steps whose median is taken as the sample period.
PERIOD_SAMPLES = 200
#: Gaps listed per topic (the count covers all of them).
SHOWN_GAPS = 20


def header_stamp_ns(data: bytes) -> int | None:
    """Header stamp [ns] of a CDR message that starts with a ``std_msgs/Header`` (None: too short)."""
    if len(data) < 12:
        return None
    sec, nanosec = struct.unpack_from("<iI", data, 4)
    return sec * 1_000_000_000 + nanosec


@dataclass
class _Topic:
    received: int = 0
    seq_lost: int = 0
    seq_seen: bool = False
    last_seq: dict[bytes, int] = field(default_factory=dict)
    # (step, log before, log, a gap already listed) until the period is known
    stamps_head: list[tuple[int, int, int, bool]] = field(default_factory=list)
    period_ns: float | None = None
    last_stamp: int | None = None
    stamp_lost: int = 0
    first_log: int | None = None
    gaps: list[tuple[int, int, int]] = field(default_factory=list)  # (log before, log after, lost)
    n_gaps: int = 0
    last_log: int | None = None


class LossCounter:
    """Counts, per topic, the messages received and those a publisher sent that never arrived.

    Call :meth:`add` for every message the recorder receives; :meth:`report` gives the per-topic
    figures stored in the bag.

    Parameters
    ----------
    stamped : callable, optional
        ``stamped(topic) -> bool``: whether the topic's messages start with a header (stamp
        counting); default: none.
    """

    def __init__(self, stamped: Any = None) -> None:
        self._topics: dict[str, _Topic] = {}
        self._stamped = stamped or (lambda topic: False)

    def add(self, topic: str, log_ns: int, data: bytes, sequence: int | None = None,
            publisher: bytes = b"") -> None:
        """Count one received message (``sequence``: its publisher's sequence number, if known)."""
        t = self._topics.setdefault(topic, _Topic())
        t.received += 1
        t.first_log = log_ns if t.first_log is None else t.first_log
        lost = 0
        if sequence:
            t.seq_seen = True
            last = t.last_seq.get(publisher)
            if last is not None and sequence > last + 1:
                lost = sequence - last - 1
                t.seq_lost += lost
            t.last_seq[publisher] = max(sequence, last or 0)
        if self._stamped(topic):
            stamp = header_stamp_ns(data)
            if stamp is not None:
                lost = max(lost, self._stamp(t, stamp, log_ns, lost > 0))
        if lost and t.last_log is not None:
            t.n_gaps += 1
            if len(t.gaps) < SHOWN_GAPS:
                t.gaps.append((t.last_log, log_ns, lost))
        t.last_log = log_ns

    @staticmethod
    def _stamp(t: _Topic, stamp: int, log_ns: int, seq_gap: bool) -> int:
        lost = 0
        if t.last_stamp is not None and stamp > t.last_stamp:
            step = stamp - t.last_stamp
            if t.period_ns is None:
                t.stamps_head.append((step, t.last_log or log_ns, log_ns, seq_gap))
                if len(t.stamps_head) >= PERIOD_SAMPLES:  # the period known: count the first steps too
                    p = float(sorted(h[0] for h in t.stamps_head)[len(t.stamps_head) // 2])
                    t.period_ns = p
                    for s, a, b, listed in t.stamps_head:
                        if s > 1.5 * p:
                            t.stamp_lost += round(s / p) - 1
                            if not listed:  # a gap the sequence numbers did not show
                                t.n_gaps += 1
                                if len(t.gaps) < SHOWN_GAPS:
                                    t.gaps.append((a, b, round(s / p) - 1))
                    t.gaps.sort()
                    t.stamps_head = []
            elif step > 1.5 * t.period_ns:
                lost = round(step / t.period_ns) - 1
                t.stamp_lost += lost
        t.last_stamp = stamp if t.last_stamp is None else max(stamp, t.last_stamp)
        return lost

    def report(self) -> dict[str, dict[str, Any]]:
        """Per topic: ``received``, ``lost``, ``expected``, ``fraction``, ``method`` (``sequence``,
        ``stamps`` or ``none``), ``period_s`` (stamps), ``gaps`` (count) and ``first_gaps`` (up
        to :data:`SHOWN_GAPS` of [from, to, lost]: log times [s] from the topic's first message)."""
        out: dict[str, dict[str, Any]] = {}
        for name, t in self._topics.items():
            # the larger count: a publisher that skips samples (an overrun) shows in the stamps only,
            # messages lost on the way in both
            by_stamps = t.period_ns is not None and (t.stamp_lost > t.seq_lost or not t.seq_seen)
            method = "stamps" if by_stamps else "sequence" if t.seq_seen else "none"
            lost = max(t.seq_lost, t.stamp_lost)
            expected = t.received + lost
            base = t.first_log or 0
            out[name] = {
                "received": t.received, "lost": lost, "expected": expected,
                "lost_by_sequence": t.seq_lost if t.seq_seen else None,
                "lost_by_stamps": t.stamp_lost if t.period_ns is not None else None,
                "fraction": lost / expected if expected else 0.0, "method": method,
                "period_s": None if t.period_ns is None else t.period_ns / 1e9,
                "gaps": t.n_gaps,
                "first_gaps": [[round((a - base) / 1e9, 4), round((b - base) / 1e9, 4), n]
                               for a, b, n in t.gaps],
            }
        return out


def loss_text(report: dict[str, dict[str, Any]]) -> str:
    """One line of a loss report: ``/aeropend/duty_cycle 964 of 3906 lost (24.7 %, sequence), ...``."""
    parts = []
    for name, r in report.items():
        if r["method"] == "none":
            parts.append(f"{name} {r['received']} (loss not countable)")
        else:
            parts.append(f"{name} {r['lost']} of {r['expected']} lost ({100 * r['fraction']:.2f} %, "
                         f"{r['method']})")
    return ", ".join(parts)


def loss_warning(source: str, report: dict[str, dict[str, Any]],
                 threshold: float = LOSS_THRESHOLD) -> str | None:
    """The warning a reader gives when a topic lost more than ``threshold`` of its messages (None:
    none did): how much, by which count, and where the first gaps are (log time from the start)."""
    bad = {n: r for n, r in report.items() if r.get("fraction", 0.0) > threshold}
    if not bad:
        return None
    parts = []
    for name, r in bad.items():
        where = ", ".join(f"{a:.3f}-{b:.3f} s ({n})" for a, b, n in r.get("first_gaps", [])[:5])
        more = f" and {r['gaps'] - 5} more" if r.get("gaps", 0) > 5 else ""
        parts.append(f"{name} lost {r['lost']} of {r['expected']} ({100 * r['fraction']:.1f} %, counted by "
                     f"{r['method']}) in {r['gaps']} gap(s)" + (f" at {where}{more}" if where else ""))
    return (f"{source}: message loss above {100 * threshold:g} %: " + "; ".join(parts)
            + "; the model sees these stretches without data")


def stored_loss(custom_data: dict[str, Any]) -> dict[str, dict[str, Any]] | None:
    """The recorder's loss report stored in a bag's ``custom_data`` (None: none, or unreadable)."""
    text = custom_data.get(LOSS_KEY)
    if not text:
        return None
    try:
        value = json.loads(text)
    except (TypeError, ValueError):
        return None
    return value if isinstance(value, dict) else None
