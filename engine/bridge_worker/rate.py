"""A bridge worker's forwarding rate: messages per second over a sliding window of counter samples.

The worker samples its cumulative ``forwarded`` counter each time it writes ``stats.json`` (every
``stats_interval`` s, about 0.5 s) and reports ``forwarded_per_s``, the counter's growth over the
last :data:`WINDOW` seconds divided by the time it took. ``plantkg status`` warns about a bridge
whose rate runs away (a loop through a bridge set up outside the plant, a publisher flooding):
a bridge loop once delivered one publish some 36,000 times per broker in 5 s while every counter
looked fine on its own.

Pure functions over a tuple of :class:`Sample` (monotonic seconds, count), so the window's edges
are unit-tested without a clock. A counter that goes down (a worker whose previous stats file was
unreadable starts again from 0) starts a new window: the samples before the drop are dropped, never
counted as a negative rate.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Seconds of samples the rate is taken over.
WINDOW = 10.0


@dataclass(frozen=True)
class Sample:
    at: float   # monotonic seconds
    count: int  # the cumulative counter at that time


def add_sample(samples: tuple[Sample, ...], at: float, count: int,
               window: float = WINDOW) -> tuple[Sample, ...]:
    """``samples`` with (``at``, ``count``) appended and those older than ``window`` s before
    ``at`` dropped; after a counter restart (``count`` below the last one) only the new sample.
    A sample not later than the last one replaces it (a clock that did not move)."""
    if samples and count < samples[-1].count:
        return (Sample(at, count),)
    if samples and at <= samples[-1].at:
        samples = samples[:-1]
    return tuple(s for s in samples if s.at >= at - window) + (Sample(at, count),)


def rate(samples: tuple[Sample, ...]) -> float:
    """Messages per second between the oldest and the newest sample; 0.0 with fewer than two
    samples or none in between (nothing measured yet is not a flood)."""
    if len(samples) < 2:
        return 0.0
    first, last = samples[0], samples[-1]
    span = last.at - first.at
    if span <= 0 or last.count <= first.count:
        return 0.0
    return (last.count - first.count) / span
