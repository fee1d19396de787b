"""The picture's time against the times of the inputs (docs/protocol.md §6.1).

One input must not move the picture far: a bad clock (a time in milliseconds, a stale
replay, a bit flip) would otherwise age every track out, or make the lockstep frames wait
for a time that never comes. An input more than `max_jump` seconds from the picture's
time is refused while the picture holds tracks. A feed that really started a new
timeline (a replay from another epoch) sends many such inputs: `confirm` of them in a
row, with no input near the picture between them, start the new timeline at the last
one. With no track held, any time is taken (there is nothing to protect).
"""

from __future__ import annotations

from .. import defaults


class Timeline:
    """Admits input times; counts the new timelines it started (`jumps`)."""

    def __init__(self, max_jump: float = defaults.MAX_JUMP,
                 confirm: int = defaults.NEW_TIMELINE) -> None:
        self.max_jump, self.confirm = max_jump, max(1, confirm)
        self.far = 0  # far inputs in a row so far
        self.jumps = 0

    def admit(self, t: float, now: float | None, tracks: int) -> tuple[str | None, bool]:
        """(reason, jump) for an input of time `t`, the picture being at `now` (None: no
        time yet) with `tracks` tracks. reason: why the input is refused (None: taken);
        jump: the input starts a new timeline (the caller moves the picture to t)."""
        if now is None or abs(t - now) <= self.max_jump:
            self.far = 0
            return None, False
        self.far += 1
        if tracks == 0 or self.far >= self.confirm:
            self.far = 0
            self.jumps += 1
            return None, True
        return (f"time t={t!r} is {t - now:+.6g} s from the picture's time t={now!r} "
                f"(limit --max-jump {self.max_jump:g} s; {self.confirm - self.far} more "
                "such inputs in a row start a new timeline)"), False
