"""``GET /metrics``: the server's counters in the Prometheus text format (version 0.0.4), written here.

Updated on the event loop only (no lock): frames answered and refused, requests by status code, the latency
of answered frames (a histogram, seconds), sessions live (a gauge), created and expired.
"""

from __future__ import annotations

import bisect
from collections import Counter

BUCKETS_S = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


class Metrics:
    """The counters (see the module docstring)."""

    def __init__(self) -> None:
        self.frames: Counter[str] = Counter()
        self.requests: Counter[int] = Counter()
        self.buckets = [0] * (len(BUCKETS_S) + 1)  # the last: above every bound (+Inf only)
        self.latency_sum = 0.0

    def answered(self, seconds: float) -> None:
        """One frame answered in ``seconds``."""
        self.frames["ok"] += 1
        self.buckets[bisect.bisect_left(BUCKETS_S, seconds)] += 1
        self.latency_sum += seconds

    def refused(self) -> None:
        """One frame refused (a bad body, an unknown session...)."""
        self.frames["refused"] += 1

    def request(self, status: int) -> None:
        self.requests[int(status)] += 1

    def render(self, sessions: int, created: int, expired: int) -> str:
        """The text exposition of every metric."""
        out = ["# HELP seqnet_serve_frames_total Frames received, by outcome.",
               "# TYPE seqnet_serve_frames_total counter"]
        out += [f'seqnet_serve_frames_total{{outcome="{k}"}} {self.frames[k]}' for k in ("ok", "refused")]
        out += ["# HELP seqnet_serve_requests_total HTTP requests answered, by status code.",
                "# TYPE seqnet_serve_requests_total counter"]
        out += [f'seqnet_serve_requests_total{{code="{c}"}} {n}' for c, n in sorted(self.requests.items())]
        out += ["# HELP seqnet_serve_frame_latency_seconds Time to read, describe and localise a frame.",
                "# TYPE seqnet_serve_frame_latency_seconds histogram"]
        total = 0
        for bound, n in zip((*BUCKETS_S, float("inf")), self.buckets, strict=True):
            total += n
            out.append(f'seqnet_serve_frame_latency_seconds_bucket{{le="{"+Inf" if bound == float("inf") else bound}"}}'
                       f" {total}")
        out += [f"seqnet_serve_frame_latency_seconds_sum {self.latency_sum:.6f}",
                f"seqnet_serve_frame_latency_seconds_count {total}",
                "# HELP seqnet_serve_sessions Sessions live.", "# TYPE seqnet_serve_sessions gauge",
                f"seqnet_serve_sessions {sessions}",
                "# HELP seqnet_serve_sessions_created_total Sessions created.",
                "# TYPE seqnet_serve_sessions_created_total counter", f"seqnet_serve_sessions_created_total {created}",
                "# HELP seqnet_serve_sessions_expired_total Sessions expired after their idle time.",
                "# TYPE seqnet_serve_sessions_expired_total counter", f"seqnet_serve_sessions_expired_total {expired}"]
        return "\n".join(out) + "\n"
