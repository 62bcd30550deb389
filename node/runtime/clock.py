"""A bed's sensor clock, robust to one bad time.

The bed's clock is the time its aligner has reached: the newest sensor time it took. A
sample within ``max_jump_s`` of that clock goes on to the aligner. A sample further from it
(ahead or behind; and, before the bed has a clock, every sample) is held apart in a
*candidate clock*: the held samples within ``max_jump_s`` of one another. A candidate is
confirmed, the bed's clock moves to it and its samples go to the aligner in arrival order, when

- ``confirm_channels`` distinct channels agree on it (every channel of a bed with fewer), or
- it holds ``confirm_samples`` samples spanning ``confirm_span_s`` of their own time, and as
  much of the node's receipt time where the node stamped them, and no sample was taken on the
  bed's clock since it began (the old clock fell silent: a bed of one or two publishing channels
  whose clock moved). The span keeps a burst of a second publisher's samples, delivered together
  before the bed's next one, from passing for silence (in the hostile soak 25 samples of a key 2 s ahead
  arrived in 64 ms and moved the bed's clock); on receipt time too, because a publisher starved
  of CPU for a while sends a burst that spans seconds of its own time in a few milliseconds
  (the hostile soak on a loaded machine: 83 samples of a second publisher taken as the bed's).

A candidate not confirmed once the bed's clock has gone ``hold_s`` past its start is dropped:
its samples are counted as clock faults (a lone sample stamped 9e9, a clock that jumped on one
key only), and, where one key put two or more samples in it, those as clock conflicts (a second
publisher on that key, with another clock). So one bad sample never moves the bed's clock, nor
anything kept from it (the engine history's ``last_on_t`` comes from aligned samples only), and
a clock that really moved (every channel, or the only ones there are) is followed within a few
samples: the aligner restarts on it as a new run when it went back, and goes on (a new run after
``RUN_GAP``) when it went forward.

Decisions depend only on the messages' order, content and receipt times (which the recording
keeps): pure, the same live and in replay.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

Held = tuple[str, float, float | None]  # (channel, t, value) of a held sample


@dataclass(frozen=True)
class ClockPolicy:
    """How far a bed's samples may stray from its clock, and what confirms a new clock.

    Attributes:
        max_jump_s: a sample further than this from the bed's clock (s, either way) is held apart.
            Above the alignment wait and the reordering a bed shows (0.25 s), below the offsets
            to be caught (a second publisher 2 s ahead). ``UNGUARDED``: inf, one channel confirms.
        confirm_channels: distinct channels that confirm a candidate clock (at most the bed's).
        confirm_samples: samples that confirm one while nothing arrives on the bed's clock...
        confirm_span_s: ... when they also span this much sensor time, s, and this much receipt
            time where the samples have one.
        hold_s: bed time a candidate waits for confirmation before it is dropped, s.
        max_held: samples held at most, every candidate of a bed (beyond: counted, not kept).
        max_candidates: candidate clocks at most; a new one drops the oldest.

    >>> ClockPolicy().max_jump_s
    1.0
    >>> ClockPolicy(max_jump_s=0)
    Traceback (most recent call last):
    ...
    ValueError: max_jump_s must be a number > 0 (inf: no guard), got 0
    """

    max_jump_s: float = 1.0
    confirm_channels: int = 3
    confirm_samples: int = 8
    confirm_span_s: float = 1.0
    hold_s: float = 2.0
    max_held: int = 1024
    max_candidates: int = 4

    def __post_init__(self) -> None:
        x = self.max_jump_s
        if not (isinstance(x, (int, float)) and x > 0 and not math.isnan(x)):
            raise ValueError(f"max_jump_s must be a number > 0 (inf: no guard), got {x!r}")
        x = self.hold_s
        if not (isinstance(x, (int, float)) and math.isfinite(x) and x > 0):
            raise ValueError(f"hold_s must be a finite number > 0, got {x!r}")
        x = self.confirm_span_s
        if not (isinstance(x, (int, float)) and math.isfinite(x) and 0 <= x < self.hold_s):
            raise ValueError(f"confirm_span_s must be a number in [0, hold_s), got {x!r}")
        for name in ("confirm_channels", "confirm_samples", "max_held", "max_candidates"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise ValueError(f"{name} must be an integer >= 1, got {getattr(self, name)!r}")

    def settings(self) -> dict[str, float | None]:
        """What a node says of its guard (its health, so that a replay of its recording guards
        alike): ``max_jump_s`` (None: no guard) and ``hold_s``.

        >>> p = ClockPolicy(max_jump_s=math.inf, hold_s=3.0)
        >>> p.settings(), ClockPolicy.from_settings(p.settings()) == p
        ({'max_jump_s': None, 'hold_s': 3.0}, True)
        """
        return {"max_jump_s": None if math.isinf(self.max_jump_s) else self.max_jump_s, "hold_s": self.hold_s}

    @classmethod
    def from_settings(cls, d: object) -> ClockPolicy:
        """The policy ``settings`` gave; a ``ValueError`` (one line) for anything else."""
        if not isinstance(d, dict) or set(d) != {"max_jump_s", "hold_s"}:
            raise ValueError(f"clock settings must be an object of max_jump_s and hold_s, got {d!r}")
        jump, hold = d["max_jump_s"], d["hold_s"]
        for name, v in (("max_jump_s", jump), ("hold_s", hold)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise ValueError(f"clock setting {name} must be a number, got {v!r}")
        if hold is None:
            raise ValueError("clock setting hold_s must be a number, got None")
        return cls(max_jump_s=math.inf if jump is None else float(jump), hold_s=float(hold))


@dataclass
class Candidate:
    """Samples held apart, within ``max_jump_s`` of one another: a clock not confirmed yet."""

    newest: float  # the newest time among them, s
    oldest: float  # the oldest time among them, s
    since: float | None  # the bed's clock when it began (None: the bed had none yet)
    taken: int  # the guard's count of samples taken on the bed's clock when it began
    received: int | None = None  # the node's receipt time of its first sample, ns (None: not known)
    samples: list[Held] = field(default_factory=list)  # in arrival order (at most the guard's share)
    per_channel: Counter[str] = field(default_factory=Counter)  # samples offered, per channel


class ClockGuard:
    """One bed's guard in front of its aligner (``Aligner`` holds one; see the module).

    ``offer`` decides on each sample of a known channel; ``taken`` counts the samples the
    aligner took on the bed's clock (its batch path adds its own).

    >>> g = ClockGuard(ClockPolicy(), n_channels=3)
    >>> [g.offer(c, 100.0, 1.0, None)[1] is not None for c in ("nB", "yB", "tF")]  # no clock yet
    [False, False, True]
    >>> g.offer("nB", 100.5, 1.0, 100.0), g.offer("nB", 9e9, 1.0, 100.5)  # near: taken; far: held
    ((True, None), (False, None))
    >>> for k in range(100):  # the bed's clock goes on; the lone sample is dropped
    ...     _ = g.offer("nB", 100.5 + k / 40, 1.0, 100.5 + k / 40)
    >>> g.faults, g.conflicts, g.jumps, g.held
    (1, 0, 0, 0)
    """

    def __init__(self, policy: ClockPolicy, n_channels: int) -> None:
        self.policy = policy
        self.max_jump = float(policy.max_jump_s)
        self.need = max(1, min(policy.confirm_channels, n_channels))
        self._share = max(1, policy.max_held // policy.max_candidates)
        self._cands: list[Candidate] = []
        self.taken = 0  # samples taken on the bed's clock
        self.faults = 0  # samples dropped: never confirmed as the bed's clock
        self.conflicts = 0  # of them, those of a key that put two or more in one candidate
        self.jumps = 0  # candidate clocks confirmed while the bed had one

    @property
    def pending(self) -> bool:
        """Whether samples are held (then every sample goes through ``offer``)."""
        return bool(self._cands)

    @property
    def held(self) -> int:
        """Samples held now, every candidate."""
        return sum(sum(c.per_channel.values()) for c in self._cands)

    def offer(self, channel: str, t: float, v: float | None, clock: float | None,
              received: int | None = None) -> tuple[bool, Candidate | None]:
        """A sample of ``channel`` at t (s), the bed's clock being ``clock`` (None: none yet),
        received by the node at ``received`` (ns on its clock; None: not known).

        Returns (take, confirmed): take it now on the bed's clock; or a candidate this sample
        confirmed (its held samples, this one last, are the bed's new clock), or None (held)."""
        if self._cands and clock is not None:
            self._expire(clock)
        jump = self.max_jump
        if clock is not None and -jump <= t - clock <= jump:
            self.taken += 1
            return True, None
        cand = next((c for c in self._cands if abs(t - c.newest) <= jump), None)
        if cand is None:
            if len(self._cands) >= self.policy.max_candidates:
                self._drop(self._cands.pop(0))
            cand = Candidate(t, t, clock, self.taken, received)
            self._cands.append(cand)
        cand.newest = max(cand.newest, t)
        cand.oldest = min(cand.oldest, t)
        cand.per_channel[channel] += 1
        if len(cand.samples) < self._share:
            cand.samples.append((channel, t, v))
        if (len(cand.per_channel) >= self.need
                or (sum(cand.per_channel.values()) >= self.policy.confirm_samples
                    and cand.newest - cand.oldest >= self.policy.confirm_span_s
                    and cand.taken == self.taken and self._spans_receipt(cand, received))):
            self._cands.remove(cand)
            self.faults += sum(cand.per_channel.values()) - len(cand.samples)  # beyond the share
            self.jumps += clock is not None
            return False, cand
        return False, None

    def _spans_receipt(self, cand: Candidate, received: int | None) -> bool:
        """Whether the candidate's samples came over ``confirm_span_s`` of receipt time, this
        one received at ``received`` (ns); True where either receipt is not known."""
        if received is None or cand.received is None:
            return True
        return received - cand.received >= self.policy.confirm_span_s * 1e9

    def _expire(self, clock: float) -> None:
        for cand in list(self._cands):
            if cand.since is None or clock < cand.since:  # (the clock itself went back since)
                cand.since = clock
            elif clock - cand.since > self.policy.hold_s:
                self._cands.remove(cand)
                self._drop(cand)

    def _drop(self, cand: Candidate) -> None:
        self.faults += sum(cand.per_channel.values())
        self.conflicts += sum(n for n in cand.per_channel.values() if n >= 2)

    def drop_all(self) -> None:
        """End of stream: every candidate still held is dropped (and counted)."""
        for cand in self._cands:
            self._drop(cand)
        self._cands.clear()


UNGUARDED = ClockPolicy(max_jump_s=math.inf, confirm_channels=1)  # every sample taken at once
