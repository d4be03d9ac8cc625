"""When a lockstep sender re-sends an unanswered node message: after a timeout learnt from how long
the fusion server took to answer the previous epochs.

A lockstep agent (and the load generator, for all its vehicles) re-sends its epoch until a
solution answers it, because a message can be lost (a server restarting, a router reconnecting).
A fixed 1-s timer re-sent every message of an epoch that merely took longer than a second to
solve: at 1000 vehicles, whose epochs take seconds, the server received and dropped one or two
duplicates of every vehicle's message per epoch, a measurable part of its CPU
(docs/performance-scale.md, "Re-sends"). TCP solved the same problem for its retransmissions:
its timeout follows a smoothed round-trip time and its variation (RFC 6298, Jacobson/Karels);
this is that estimator over "epoch sent -> first answer". It lives here rather than in a library
because nothing in the stack exposes one (Zenoh's reliability is per hop, not an application's
answer), and it is a few lines.

Within one epoch the load generator doubles the wait after each re-send, as TCP backs off
(RFC 6298, 5.5): a round of its re-sends is one message per unanswered vehicle, hundreds at once,
so a server that is only slow must not be buried in them. A lone agent re-sends one small message
per timeout and does not back off: after a server restart its next copy is what lets the new
server solve the epoch, so a doubled wait would be a doubled gap in the vehicle's solutions.
"""

from __future__ import annotations

from dataclasses import dataclass

ALPHA = 1.0 / 8.0  # RFC 6298's gains for the smoothed round trip and its variation
BETA = 1.0 / 4.0
K = 4.0  # the timeout is the smoothed round trip plus K variations
MAX_RESEND_S = 10.0  # a message lost to a restarting server is re-sent within this at worst


@dataclass
class ResendTimer:
    """Re-send timeout from the answers' round trips: `min_s` (the `resend_s` setting) until one
    was measured and whenever answers are quick, at most `max_s`."""

    min_s: float
    max_s: float = MAX_RESEND_S
    srtt_s: float | None = None
    rttvar_s: float = 0.0

    def answered(self, round_trip_s: float) -> None:
        """An epoch was answered `round_trip_s` after it was sent (its first send: a re-send does
        not restart the server's solve, so the epoch's own time is the one to learn).

        Re-sent epochs are sampled too, unlike TCP's Karn rule: a fleet whose every epoch takes
        longer than `resend_s` would otherwise never learn. The price is that an outage (a server
        restarting) is one long sample, which raises the timeout, at most to `max_s`, until the
        next quick answers bring it down again."""
        r = max(0.0, round_trip_s)
        if self.srtt_s is None:
            self.srtt_s, self.rttvar_s = r, r / 2.0
            return
        self.rttvar_s = (1.0 - BETA) * self.rttvar_s + BETA * abs(self.srtt_s - r)
        self.srtt_s = (1.0 - ALPHA) * self.srtt_s + ALPHA * r

    def timeout_s(self) -> float:
        """Seconds without an answer before the first re-send of an epoch."""
        if self.srtt_s is None:
            return self.min_s
        return min(max(self.min_s, self.srtt_s + K * self.rttvar_s), max(self.min_s, self.max_s))
